"""liquidtwin's robot-side client library and ``liquidtwin-client`` command line.

>>> from liquidtwin_client import Client
>>> with Client(connect="tcp/127.0.0.1:7447") as client:
...     s = client.create_session(scene_spec, session_id="robot-1", tracking="warp_field")
...     s.publish_camera("cam0", K, D, 640, 480)          # K (3, 3) px, D (5,) plumb_bob
...     s.publish_mask("cam0", mask)                       # (480, 640) bool, stamp = now
...     s.publish_poses({"cup": pose, "cam0": cam_pose})   # (7,) each: a frame
...     for out in s.outputs(timeout=1.0):
...         if out.stream == "particles":
...             positions, speed = decode_particles(out.message)   # (N, 3) m, (N,) m/s
...     s.close()

No torch: this package depends only on numpy, protobuf, Zenoh, mcap and liquidtwin_proto.
"""

from .connection import (CREATE_TIMEOUT_S, DEFAULT_CONNECT, RPC_TIMEOUT_S, TRACKING_MODES, Client,
                         ServerError, tracking_mode)
from .models import Discrepancy, model_text
from .messages import (STREAM_TYPES, Output, decode_particles, encode_camera, encode_image,
                       encode_mask, encode_poses)
from .recording import ChannelSummary, RecordingError, RecordingSummary, summarize_recording
from .replay import Frame, InputSample, Replay, load_replay
from .results import ResultMessage, ResultsWriter, read_results
from .session import Inference, ObjectMeshArrays, SessionHandle
from .stream import RATES, StreamAborted, stream_replay
from .summary import StreamSummary, Tally, format_table

__all__ = [
    "CREATE_TIMEOUT_S", "ChannelSummary", "Client", "DEFAULT_CONNECT", "Discrepancy", "Frame", "InputSample",
    "ObjectMeshArrays", "Output", "RATES", "RPC_TIMEOUT_S", "RecordingError",
    "RecordingSummary", "Replay", "ResultMessage", "ResultsWriter", "STREAM_TYPES",
    "Inference", "ServerError", "SessionHandle", "StreamAborted", "StreamSummary", "TRACKING_MODES", "Tally",
    "decode_particles", "encode_camera", "encode_image", "encode_mask", "encode_poses",
    "format_table", "load_replay", "model_text", "read_results", "stream_replay", "summarize_recording",
    "tracking_mode",
]
