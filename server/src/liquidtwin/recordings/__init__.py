"""Recordings: MCAP files with Foxglove schemas, written by the generator and read by the server.

A recording holds measured data only (object poses from a tracker, camera calibration and
extrinsics, binary liquid masks, optional RGB); the topic layout is documented in
:mod:`liquidtwin.recordings.topics`.

>>> with RecordingWriter("pour.mcap", spec) as rec:
...     rec.write_camera("cam0", CameraInfo("cam0", 640, 480, K, D, pose), 0)
...     rec.write_poses(0, ["cup", "bowl"], poses)
...     rec.write_mask("cam0", 0, mask)
>>> rec = read_recording("pour.mcap")
>>> rec.poses.shape, rec.masks["cam0"][1].shape      # (T, 2, 7), (M, 480, 640)
"""

from .base import CameraInfo, RecordingError
from .reader import Event, PoseSample, Recording, iter_messages, read_recording
from .topics import (KINDS, SCENE_TOPIC, TF_TOPIC, WORLD_FRAME, camera_topic, classify)
from .writer import RecordingWriter

__all__ = [
    "CameraInfo", "Event", "KINDS", "PoseSample", "Recording", "RecordingError",
    "RecordingWriter", "SCENE_TOPIC", "TF_TOPIC", "WORLD_FRAME", "camera_topic", "classify",
    "iter_messages", "read_recording",
]
