"""Recording → input samples (checked against an independent MCAP decode and the truth
sidecar), RESULTS.mcap round trip, and the run summary's arithmetic."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from liquidtwin_proto import Metrics, SceneObject, SceneSpec, SessionStatus, Volumes, make_header
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_protobuf.decoder import DecoderFactory
from mcap_protobuf.schema import register_schema

from liquidtwin_client import (Output, RecordingError, ResultsWriter, Tally, format_table,
                               load_replay, read_results)

GOLDEN = Path(__file__).resolve().parents[1] / "server" / "data" / "golden_pour_dump.mcap"
T0 = 1_767_225_600_000_000_000


def _decoded(path):
    with open(path, "rb") as f:
        return [(ch.topic, m.log_time, msg) for _, ch, m, msg in
                make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]


def test_golden_recording_replays_every_stamp_in_order():
    replay = load_replay(GOLDEN)
    truth = np.load(GOLDEN.with_suffix(".truth.npz"))
    sidecar = json.loads(GOLDEN.with_suffix(".truth.json").read_text())
    ref = _decoded(GOLDEN)
    # one frame per recorded pose stamp, the stamps of the truth sidecar
    np.testing.assert_array_equal([f.stamp_ns for f in replay.frames], truth["pose_stamps_ns"])
    # per stamp: calibration, then mask, then one poses sample (merged), nothing lost
    for frame in replay.stamps:
        streams = [s.stream for s in frame.samples]
        assert streams == sorted(streams, key=["camera", "mask", "image", "poses"].index)
        assert streams.count("poses") == 1 and streams[-1] == "poses"
    # (the reference decoder builds its own classes: compare serialized bytes)
    masks = {t: m.SerializeToString() for topic, t, m in ref if topic.endswith("/mask")}
    got_masks = {s.stamp_ns: s.payload for f in replay.stamps
                 for s in f.samples if s.stream == "mask"}
    assert got_masks == masks and len(masks) == sidecar["frames"]["written"]
    # every recorded transform arrives at its stamp with the same numbers
    want = {}
    for topic, t, msg in ref:
        if topic == "/tf":
            for tf in msg.transforms:
                want[(t, tf.child_frame_id)] = tf.SerializeToString()
    got = {(f.stamp_ns, tf.child_frame_id): tf.SerializeToString() for f in replay.frames
           for s in f.samples if s.stream == "poses"
           for tf in FrameTransforms.FromString(s.payload).transforms}
    assert got == want
    first = FrameTransforms.FromString(replay.frames[0].samples[-1].payload)
    assert {tf.child_frame_id for tf in first.transforms} == {"thermal", "source", "target",
                                                              "table"}
    # the session spec: the recorded scene (header dropped) and the calibrated camera
    spec = replay.session_spec("open_loop")
    scene = next(m for topic, _, m in ref if topic == "/scene")
    scene.ClearField("header")
    assert spec.scene.SerializeToString() == scene.SerializeToString() and spec.tracking == 1
    (cam,) = spec.cameras
    cal = next(m for topic, _, m in ref if topic.endswith("/calibration"))
    assert (cam.name, cam.width, cam.height) == ("thermal", cal.width, cal.height)
    assert list(cam.k) == list(cal.K) and list(cam.d) == list(cal.D)
    np.testing.assert_allclose(cam.pose, sidecar["cameras"]["thermal"]["true_pose"], atol=1e-12)


def _write(path, messages, scene=True):
    """MCAP with the given (topic, message, log_time) list (and a /scene first)."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        channels = {}
        items = [("/scene", SceneSpec(name="s", objects=[SceneObject(name="cup"),
                                                         SceneObject(name="bowl")]), T0)] \
            if scene else []
        for topic, msg, t in items + messages:
            if topic not in channels:
                channels[topic] = w.register_channel(topic, "protobuf",
                                                     register_schema(w, type(msg)))
            w.add_message(channels[topic], t, msg.SerializeToString(), t)
        w.finish()
    return path


def _tf(child, stamp, parent="world", x=0.0):
    tf = FrameTransform(parent_frame_id=parent, child_frame_id=child)
    tf.timestamp.FromNanoseconds(stamp)
    tf.translation.x = x
    tf.rotation.w = 1.0
    return tf


def test_other_pose_schemas_stamps_and_image_topics(tmp_path):
    pif = PosesInFrame(frame_id="world")
    pif.timestamp.FromNanoseconds(T0 + 20)
    for x in (1.0, 2.0):
        p = pif.poses.add()
        p.position.x, p.orientation.w = x, 1.0
    img = CompressedImage(format="jpeg", data=b"jpg")  # no frame_id: camera from the topic
    img.timestamp.FromNanoseconds(T0 + 10)
    late = RawImage(frame_id="cam", encoding="mono8", width=1, height=1, step=1, data=b"\xff")
    path = _write(tmp_path / "r.mcap", [
        ("/cam/image", img, T0 + 999),  # message stamp wins over the log time
        ("/pose", _tf("cup", T0 + 10, x=3.0), T0 + 10),
        ("/poses", pif, T0 + 20),
        ("/cam/liquid_mask", late, T0 + 20),  # no message stamp: the log time
        ("/calib", CameraCalibration(frame_id="cam", width=1, height=1, K=[1] * 9, D=[0] * 5),
         T0 + 20),
    ])
    replay = load_replay(path)
    assert [(f.stamp_ns, [(s.stream, s.name) for s in f.samples]) for f in replay.stamps] == [
        (T0 + 10, [("image", "cam"), ("poses", "")]),
        (T0 + 20, [("camera", "cam"), ("mask", "cam"), ("poses", "")]),
    ]
    assert CompressedImage.FromString(replay.stamps[0].samples[0].payload).frame_id == "cam"
    tfs = FrameTransforms.FromString(replay.stamps[1].samples[-1].payload).transforms
    assert [(t.child_frame_id, t.translation.x) for t in tfs] == [("cup", 1.0), ("bowl", 2.0)]
    assert replay.session_spec().cameras[0].pose == []


@pytest.mark.parametrize("messages, scene, match", [
    ([("/tf", FrameTransforms(transforms=[_tf("cup", T0, parent="base")]), T0)], True,
     "needs poses in 'world'"),
    ([("/tf", FrameTransforms(transforms=[_tf("cup", T0)]), T0)], False, "no liquidtwin.v1"),
    ([("/img", CompressedImage(format="png", data=b"x"), T0)], True, "names no camera"),
])
def test_unusable_recordings_are_named(tmp_path, messages, scene, match):
    with pytest.raises(RecordingError, match=match):
        load_replay(_write(tmp_path / "bad.mcap", messages, scene))
    with pytest.raises(RecordingError, match="no such file"):
        load_replay(tmp_path / "missing.mcap")


def _output(stream, msg, stamp, received, seq=0):
    return Output(stream, make_header("s", seq, stamp), msg, msg.SerializeToString(), received)


def test_results_mcap_reads_back_in_foxglove_form(tmp_path):
    vols = Volumes(header=make_header("s", 0, T0))
    vols.containers.add(name="cup", ml=12.5)
    metrics = Metrics(input_seq=4, iou=0.75)
    with ResultsWriter(tmp_path / "out" / "R.mcap") as w:
        w.write_status(SessionStatus(session_id="s", state="running"), received_ns=T0 - 5)
        w.write(_output("volumes", vols, T0, T0 + 300, seq=3))
        w.write(_output("metrics", metrics, T0, T0 + 200))
    # an independent decoder reads it from the embedded schemas alone
    ref = _decoded(tmp_path / "out" / "R.mcap")
    assert [(t, lt) for t, lt, _ in ref] == [("/session", T0 - 5), ("/out/metrics", T0 + 200),
                                            ("/out/volumes", T0 + 300)]
    assert ref[2][2].containers[0].ml == 12.5 and ref[1][2].iou == 0.75
    back = read_results(tmp_path / "out" / "R.mcap")
    assert sorted(back) == ["metrics", "session", "volumes"]
    (v,) = back["volumes"]
    assert (v.log_time_ns, v.publish_time_ns, v.message) == (T0 + 300, T0, vols)
    assert back["session"][0].message.state == "running"


def test_tally_numbers_match_hand_computed_values():
    tally = Tally()
    for i in range(100):  # frame i answered (i + 1) ms after it was sent
        tally.sent(T0 + i, 1_000 * i)
        tally.add(_output("particles", RawImage(), T0 + i, 1_000 * i + (i + 1) * 1_000_000))
    tally.sent(T0 + 100, 0)  # never answered
    for stamp, iou, stale in ((T0 + 1, 0.25, 2), (T0 + 2, math.nan, 5), (T0 + 3, 0.75, 4)):
        tally.add(_output("metrics", Metrics(iou=iou, dropped_stale=stale, rejected=1),
                          stamp, 0))
    for stamp, ml in ((T0 + 9, 9.0), (T0 + 5, 5.0)):  # the newest stamp wins, not the last
        v = Volumes()
        v.containers.add(name="cup", ml=ml)
        tally.add(_output("volumes", v, stamp, 0))
    s = tally.summary("s", "max", "warp_field", lost_outputs=2, wall_s=1.5)
    assert (s.frames_sent, s.frames_answered, s.iou_frames) == (101, 100, 2)
    assert s.mean_iou == pytest.approx(0.5) and s.final_volumes_ml == {"cup": 9.0}
    # latencies 1..100 ms: linear-interpolated percentiles 50.5 and 99.01
    assert s.latency_ms_p50 == pytest.approx(50.5) and s.latency_ms_p99 == pytest.approx(99.01)
    assert s.latency_ms_max == pytest.approx(100.0)
    assert (s.dropped_stale, s.rejected, s.lost_outputs) == (5, 1, 2)
    assert s.outputs == {"metrics": 3, "particles": 100, "volumes": 2}
    json.dumps(s.to_json())
    table = format_table(s)
    assert "101 / 100" in table and "final volume cup" in table and "p99 99.0 ms" in table
    empty = Tally().summary("s", "realtime", "open_loop")
    assert empty.mean_iou is None and empty.latency_ms_p50 is None
    assert "mean IOU" in format_table(empty)
