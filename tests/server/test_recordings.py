"""Recordings: MCAP writer and reader for measured data (liquidtwin issue 3).

References: the plain ``mcap`` reader with the ``foxglove_schemas_protobuf`` classes (and
classes rebuilt from the schemas embedded in the file), OpenCV codecs, hand-written "user"
MCAPs with other topic names and message types, analytic slerp.
"""

from __future__ import annotations

import hashlib
import math
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.timestamp_pb2 import Timestamp
from liquidtwin_proto import SceneObject, SceneSpec
from mcap.reader import make_reader
from mcap.writer import Writer as RawWriter
from mcap_protobuf.schema import register_schema
from mcap_protobuf.writer import Writer as ProtoWriter

from liquidtwin.recordings import (CameraInfo, RecordingError, RecordingWriter, iter_messages,
                                   read_recording)

H, W = 24, 32
K = np.array([[40.0, 0.0, 15.5], [0.0, 41.0, 11.5], [0.0, 0.0, 1.0]])
D = np.array([0.05, -0.01, 0.001, -0.002, 0.0005])
DT = 16_666_667
T0 = 1_700_000_000_000_000_000  # Unix-epoch stamps, as a real robot logs them


def _quats(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _spec():
    return SceneSpec(
        name="pour", motion="tilt", motion_params={"angle": 1.2, "speed": 0.5, "a": 3.0},
        duration_s=1.0, cameras=["cam0"],
        objects=[SceneObject(name="cup", model="cup", params={"radius": 0.04, "wall": 0.003},
                             container=True, initial_pose=[0, 0, 0, 0, 0, 0, 1]),
                 SceneObject(name="bowl", model="bowl", container=True)])


def _camera(rng, name="cam0"):
    return CameraInfo(name, W, H, K, D, np.r_[0.1, 0.4, -0.6, _quats(rng, 1)[0]])


def _content(seed=0, frames=6):
    """Inputs of a sample recording: camera, per-frame stamps, poses (F, 2, 7), masks, rgb."""
    rng = np.random.default_rng(seed)
    times = T0 + DT * np.arange(frames)
    poses = np.concatenate([rng.normal(size=(frames, 2, 3)),
                            _quats(rng, 2 * frames).reshape(frames, 2, 4)], axis=2)
    masks = rng.random((frames, H, W)) > 0.6
    yy, xx = np.mgrid[0:H, 0:W]
    smooth = np.stack([xx * 7, yy * 9, (xx + yy) * 4], axis=2).astype(np.uint8)  # jpeg-friendly
    rgb = [np.roll(smooth, i, axis=1) for i in range(frames)]
    return _camera(rng), times, poses, masks, rgb


def _write(path, content, spec=None, **kw):
    cam, times, poses, masks, rgb = content
    with RecordingWriter(path, spec if spec is not None else _spec(), **kw) as rec:
        rec.write_camera("cam0", cam, int(times[0]))
        for i, t in enumerate(times):
            rec.write_poses(int(t), ["cup", "bowl"], poses[i])
            rec.write_mask("cam0", int(t), masks[i])
            rec.write_image("cam0", int(t), rgb[i], "png" if i % 2 else "jpeg")
    return path


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    content = _content()
    return _write(tmp_path_factory.mktemp("rec") / "sample.mcap", content), content


def _ts(ns):
    return Timestamp(seconds=ns // 10**9, nanos=ns % 10**9)


def _tf(t, parent, child, p):
    return FrameTransform(timestamp=_ts(t), parent_frame_id=parent, child_frame_id=child,
                          translation=Vector3(x=p[0], y=p[1], z=p[2]),
                          rotation=Quaternion(x=p[3], y=p[4], z=p[5], w=p[6]))


def _calibration(frame_id="cam0", width=W, height=H, t=T0, model="plumb_bob", d=D):
    return CameraCalibration(timestamp=_ts(t), frame_id=frame_id, width=width, height=height,
                             distortion_model=model, D=list(d), K=K.ravel().tolist())


def _user_file(path, messages, *, log_offset=0):
    """A "user" MCAP written with mcap-protobuf-support: [(topic, message, stamp ns)]."""
    with open(path, "wb") as f, ProtoWriter(f) as w:
        for topic, msg, t in messages:
            w.write_message(topic, msg, log_time=t + log_offset, publish_time=t)
    return path


# ------------------------------------------------------------------ round trip

def test_round_trip_is_exact(sample):
    path, (cam, times, poses, masks, rgb) = sample
    rec = read_recording(path)
    assert rec.spec == _spec()
    assert rec.object_names == ["cup", "bowl"]
    assert rec.pose_times_ns.dtype == np.int64 and np.array_equal(rec.pose_times_ns, times)
    assert rec.poses.dtype == np.float64 and np.array_equal(rec.poses, poses)  # bit-exact
    assert rec.cameras == {"cam0": cam}
    assert np.array_equal(rec.camera_poses["cam0"][1], cam.pose[None])
    mt, mm = rec.masks["cam0"]
    assert np.array_equal(mt, times) and mm.dtype == np.bool_ and np.array_equal(mm, masks)
    it, imgs = rec.images["cam0"]
    assert np.array_equal(it, times)
    for i, img in enumerate(imgs):
        assert img.shape == (H, W, 3) and img.dtype == np.uint8
        if i % 2:  # png is lossless
            assert np.array_equal(img, rgb[i])
        else:  # jpeg q95 of a smooth image: close, and channels not swapped
            assert np.abs(img.astype(int) - rgb[i]).mean() < 4.0
    assert rec.duration_s == pytest.approx((times[-1] - times[0]) * 1e-9)
    assert np.array_equal(rec.poses_at(int(times[2])), poses[2])
    no_rgb = read_recording(path, images=False)
    assert no_rgb.images == {} and np.array_equal(no_rgb.masks["cam0"][1], masks)


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_round_trip_other_compressions(tmp_path, compression):
    content = _content(seed=3, frames=2)
    rec = read_recording(_write(tmp_path / "c.mcap", content, compression=compression))
    assert np.array_equal(rec.poses, content[2])
    assert np.array_equal(rec.masks["cam0"][1], content[3])
    with open(tmp_path / "c.mcap", "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert {c.compression for c in chunks} == {"" if compression == "none" else compression}


def _classes_from_schema(schema):
    """Message class rebuilt only from the FileDescriptorSet embedded in the file."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def test_plain_mcap_reader_decodes_every_message(sample):
    path, (cam, times, poses, masks, rgb) = sample
    classes = {c.DESCRIPTOR.full_name: c for c in (FrameTransforms, CameraCalibration, RawImage,
                                                   CompressedImage, SceneSpec)}
    seen = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        header, summary = reader.get_header(), reader.get_summary()
        assert header.library == "liquidtwin.recordings/1" and header.profile == ""
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert list(reader.iter_metadata()) == [] and list(reader.iter_attachments()) == []
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
            msg = classes[schema.name].FromString(message.data)
            assert _classes_from_schema(schema).FromString(message.data).SerializeToString(
                deterministic=True) == msg.SerializeToString(deterministic=True)
            assert message.log_time == message.publish_time
            if schema.name != "liquidtwin.v1.SceneSpec":
                ts = msg.transforms[0].timestamp if schema.name == "foxglove.FrameTransforms" \
                    else msg.timestamp
                assert message.log_time == ts.seconds * 10**9 + ts.nanos
            seen.setdefault((channel.topic, schema.name), []).append(msg)
    assert {k: len(v) for k, v in seen.items()} == {
        ("/scene", "liquidtwin.v1.SceneSpec"): 1, ("/tf", "foxglove.FrameTransforms"): 7,
        ("/camera/cam0/calibration", "foxglove.CameraCalibration"): 1,
        ("/camera/cam0/mask", "foxglove.RawImage"): 6,
        ("/camera/cam0/image", "foxglove.CompressedImage"): 6}
    assert seen[("/scene", "liquidtwin.v1.SceneSpec")][0] == _spec()
    cal = seen[("/camera/cam0/calibration", "foxglove.CameraCalibration")][0]
    assert (cal.frame_id, cal.width, cal.height) == ("cam0", W, H)
    assert cal.distortion_model == "plumb_bob"
    assert list(cal.K) == K.ravel().tolist() and list(cal.D) == D.tolist()
    assert list(cal.R) == np.eye(3).ravel().tolist()
    assert list(cal.P) == np.c_[K, np.zeros(3)].ravel().tolist()
    tfs = seen[("/tf", "foxglove.FrameTransforms")]
    cam_tf = tfs[0].transforms[0]  # write_camera came first
    assert (cam_tf.parent_frame_id, cam_tf.child_frame_id) == ("world", "cam0")
    for i, msg in enumerate(tfs[1:]):
        assert [(t.parent_frame_id, t.child_frame_id) for t in msg.transforms] == \
            [("world", "cup"), ("world", "bowl")]
        got = [[t.translation.x, t.translation.y, t.translation.z, t.rotation.x, t.rotation.y,
                t.rotation.z, t.rotation.w] for t in msg.transforms]
        assert np.array_equal(got, poses[i])
    for i, m in enumerate(seen[("/camera/cam0/mask", "foxglove.RawImage")]):
        assert (m.encoding, m.width, m.height, m.step, m.frame_id) == ("mono8", W, H, W, "cam0")
        assert np.array_equal(np.frombuffer(m.data, np.uint8).reshape(H, W), masks[i] * 255)
    for i, m in enumerate(seen[("/camera/cam0/image", "foxglove.CompressedImage")]):
        assert m.format == ("png" if i % 2 else "jpeg") and m.frame_id == "cam0"
        bgr = cv2.imdecode(np.frombuffer(m.data, np.uint8), cv2.IMREAD_COLOR)
        assert bgr.shape == (H, W, 3)
        if i % 2:
            assert np.array_equal(bgr[:, :, ::-1], rgb[i])


# ------------------------------------------------------------------ streaming

def test_iter_messages_time_order_and_payloads(tmp_path):
    cam, times, poses, masks, rgb = _content(seed=1, frames=4)
    path = tmp_path / "s.mcap"
    with RecordingWriter(path, _spec()) as rec:  # all poses first, then all masks: file order
        rec.write_camera("cam0", cam, int(times[0]))  # is not time order
        for i, t in enumerate(times):
            rec.write_poses(int(t), ["cup", "bowl"], poses[i])
        for i, t in enumerate(times):
            rec.write_mask("cam0", int(t), masks[i])
            rec.write_image("cam0", int(t), rgb[i], "png")
    events = list(iter_messages(path))
    stamps = [e.t_ns for e in events]
    assert stamps == sorted(stamps)
    assert events[0].kind == "scene" and events[0].payload == _spec()
    kinds = [e.kind for e in events]
    assert kinds.count("poses") == 4 and kinds.count("mask") == 4 and kinds.count("image") == 4
    assert kinds.count("camera") == 2  # its calibration and its transform
    got = [e.payload for e in events if e.kind == "poses"]
    assert all(g.names == ("cup", "bowl") for g in got)
    assert np.array_equal(np.stack([g.poses for g in got]), poses)
    assert np.array_equal(np.stack([e.payload for e in events if e.kind == "mask"]), masks)
    assert all(e.payload == cam for e in events if e.kind == "camera")
    assert np.array_equal([e.payload for e in events if e.kind == "image"], rgb)
    assert "image" not in {e.kind for e in iter_messages(path, images=False)}


def test_moving_camera_is_taken_per_time(tmp_path):
    rng = np.random.default_rng(2)
    cam = _camera(rng)
    axis = np.array([1.0, 2.0, 2.0]) / 3.0

    def pose(tx, angle):
        return np.r_[tx, 0.0, 0.0, axis * math.sin(angle / 2), math.cos(angle / 2)]

    path = tmp_path / "m.mcap"
    with RecordingWriter(path, None) as rec:
        rec.write_camera("cam0", cam.with_pose(pose(0.0, 0.2)), 0)
        rec.write_poses(0, ["cup"], [pose(0.0, 0.0)])
        rec.write_camera("cam0", cam.with_pose(pose(1.0, 1.0)), 10**9)
        rec.write_poses(10**9, ["cup"], [pose(0.0, 0.0)])
    r = read_recording(path)
    assert r.spec is None and r.object_names == ["cup"]
    assert np.array_equal(r.cameras["cam0"].pose, pose(0.0, 0.2))  # the first pose
    assert np.array_equal(r.camera_poses["cam0"][0], [0, 10**9])
    mid = r.camera_at("cam0", 250_000_000).pose  # slerp about a fixed axis: angle is linear
    np.testing.assert_allclose(mid, pose(0.25, 0.4), atol=1e-12)
    assert np.array_equal(r.camera_at("cam0", 2 * 10**9).pose, pose(1.0, 1.0))
    assert r.camera_at("cam0", 10**9).same_intrinsics(cam)


# ------------------------------------------------------------------ user files

def test_user_mcap_found_by_schema(tmp_path):
    """Other topic names, singular FrameTransform messages at staggered stamps, png masks
    named by frame_id, bgr8 raw RGB with row padding, log time ≠ stamp, no scene."""
    rng = np.random.default_rng(4)
    cup = np.c_[rng.normal(size=(3, 3)), _quats(rng, 3)]
    lid = np.c_[rng.normal(size=(2, 3)), _quats(rng, 2)]
    cam_pose = np.r_[0.0, 1.0, 0.0, _quats(rng, 1)[0]]
    masks = rng.random((2, H, W)) > 0.5
    bgr = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    padded = np.zeros((H, W * 3 + 5), np.uint8)
    padded[:, :W * 3] = bgr.reshape(H, -1)
    msgs = [("/kinect/info", _calibration("kinect", model="", d=[]), T0),
            ("/tracker", _tf(T0, "world", "kinect", cam_pose), T0)]
    for i in range(3):
        msgs.append(("/tracker", _tf(T0 + 2 * i * DT, "world", "cup", cup[i]), T0 + 2 * i * DT))
    for i in range(2):
        msgs.append(("/tracker", _tf(T0 + (4 * i + 1) * DT, "world", "lid", lid[i]),
                     T0 + (4 * i + 1) * DT))
        png = cv2.imencode(".png", masks[i].astype(np.uint8) * 255)[1].tobytes()
        msgs.append(("/kinect/liquid_mask", CompressedImage(
            timestamp=_ts(T0 + i * DT), frame_id="kinect", data=png, format="png"), T0 + i * DT))
    msgs.append(("/kinect/color", RawImage(timestamp=_ts(T0), frame_id="kinect", width=W,
                                           height=H, encoding="bgr8", step=W * 3 + 5,
                                           data=padded.tobytes()), T0))
    msgs.append(("/diagnostics", Vector3(x=1.0), T0))  # unknown schema: ignored
    msgs.sort(key=lambda m: m[2])
    path = _user_file(tmp_path / "user.mcap", msgs, log_offset=12345)
    r = read_recording(path)
    assert r.spec is None and r.object_names == ["cup", "lid"]
    assert np.array_equal(r.pose_times_ns, T0 + DT * np.array([0, 1, 2, 4, 5]))
    assert np.array_equal(r.poses[[0, 2, 3], 0], cup)  # exact at its own samples
    assert np.array_equal(r.poses[[1, 4], 1], lid)
    np.testing.assert_allclose(r.poses[1, 0, :3], (cup[0, :3] + cup[1, :3]) / 2, atol=1e-12)
    np.testing.assert_array_equal(r.poses[0, 1], lid[0])  # held before its first sample
    assert r.cameras["kinect"] == CameraInfo("kinect", W, H, K, np.zeros(5), cam_pose)
    assert np.array_equal(r.masks["kinect"][1], masks)
    assert np.array_equal(r.masks["kinect"][0], T0 + DT * np.arange(2))
    assert np.array_equal(r.images["kinect"][1][0], bgr[:, :, ::-1])
    events = list(iter_messages(path))
    assert [e.t_ns for e in events] == sorted(e.t_ns for e in events) and events[0].t_ns == T0
    kinds = sorted(e.kind for e in events)
    assert kinds == ["camera"] * 2 + ["image"] + ["mask"] * 2 + ["poses"] * 5


def test_user_poses_in_frame_raw_01_masks_and_topic_override(tmp_path):
    rng = np.random.default_rng(5)
    poses = np.c_[rng.normal(size=(2, 3)), _quats(rng, 2)]
    mask = rng.random((H, W)) > 0.5
    spec = SceneSpec(objects=[SceneObject(name="cup"), SceneObject(name="bowl")])
    pif = PosesInFrame(timestamp=_ts(T0), frame_id="world", poses=[
        Pose(position=Vector3(x=p[0], y=p[1], z=p[2]),
             orientation=Quaternion(x=p[3], y=p[4], z=p[5], w=p[6])) for p in poses])
    liquid = RawImage(timestamp=_ts(T0), frame_id="c1", width=W, height=H, encoding="8UC1",
                      data=mask.astype(np.uint8).tobytes())  # 0/1 values
    msgs = [("/my_scene", spec, T0), ("/objects", pif, T0), ("/cal", _calibration("c1"), T0),
            ("/tf", FrameTransforms(transforms=[_tf(T0, "world", "c1", poses[0])]), T0),
            ("/thermal/liquid", liquid, T0)]
    path = _user_file(tmp_path / "pif.mcap", msgs)
    r = read_recording(path)
    assert r.spec == spec and np.array_equal(r.poses[0], poses)
    assert r.masks == {} and r.images["c1"][1][0].shape == (H, W, 3)  # no 'mask' in the name
    r = read_recording(path, topics={"/thermal/liquid": "mask"})
    assert np.array_equal(r.masks["c1"][1][0], mask) and r.images == {}
    with pytest.raises(RecordingError, match="not in the file"):
        read_recording(path, topics={"/nope": "mask"})
    with pytest.raises(RecordingError, match="cannot hold mask"):
        read_recording(path, topics={"/objects": "mask"})
    with pytest.raises(ValueError, match="kind must be one of"):
        read_recording(path, topics={"/objects": "depth"})


def test_unchunked_mcap_without_summary(tmp_path):
    """Written with the bare mcap writer: no chunks, no indexes, no CRCs."""
    rng = np.random.default_rng(6)
    pose = np.r_[1.0, 2.0, 3.0, _quats(rng, 1)[0]]
    path = tmp_path / "flat.mcap"
    with open(path, "wb") as f:
        w = RawWriter(f, use_chunking=False, repeat_channels=False, repeat_schemas=False,
                      use_statistics=False, use_summary_offsets=False, enable_crcs=False)
        w.start()
        sid = register_schema(w, FrameTransforms)
        cid = w.register_channel("/poses", "protobuf", sid)
        msg = FrameTransforms(transforms=[_tf(0, "world", "cup", pose)])
        w.add_message(cid, log_time=5, publish_time=5, data=msg.SerializeToString())
        w.finish()
    r = read_recording(path)
    assert np.array_equal(r.pose_times_ns, [5]) and np.array_equal(r.poses[0, 0], pose)


# ------------------------------------------------------------------ determinism

_DETERMINISM_SCRIPT = """
import hashlib, sys
sys.path.insert(0, {tests!r})
import test_recordings as t
t._write({path!r}, t._content())
print(hashlib.sha256(open({path!r}, 'rb').read()).hexdigest())
"""


def test_same_content_gives_identical_bytes(tmp_path, sample):
    a = _write(tmp_path / "a.mcap", _content())
    assert a.read_bytes() == sample[0].read_bytes()
    assert _write(tmp_path / "b.mcap", _content(seed=1)).read_bytes() != a.read_bytes()
    script = _DETERMINISM_SCRIPT.format(tests=os.path.dirname(__file__),
                                        path=str(tmp_path / "c.mcap"))
    env = dict(os.environ, PYTHONHASHSEED="12345", OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                         timeout=120, check=True).stdout.split()[-1]
    assert out == hashlib.sha256(a.read_bytes()).hexdigest()


# ------------------------------------------------------------------ damaged files

def test_truncated_files_are_refused(tmp_path, sample):
    data = sample[0].read_bytes()
    for cut in (1, 7, 8, 30, len(data) // 3, len(data) // 2, len(data) - 40, len(data) - 9,
                len(data) - 1):
        path = tmp_path / f"cut{cut}.mcap"
        path.write_bytes(data[:cut])
        with pytest.raises(RecordingError, match="truncated|damaged") as e:
            read_recording(path)
        assert str(path) in str(e.value)
        with pytest.raises(RecordingError):
            next(iter_messages(path))


def test_flipped_bytes_are_refused(tmp_path, sample):
    data = sample[0].read_bytes()
    rng = np.random.default_rng(7)
    positions = list(rng.choice(len(data), 40, replace=False)) + [0, 9, 20, len(data) - 1,
                                                                   len(data) - 10, len(data) - 30]
    for pos in positions:
        bad = bytearray(data)
        bad[pos] ^= 1 << int(rng.integers(8))
        path = tmp_path / "flip.mcap"
        path.write_bytes(bytes(bad))
        with pytest.raises(RecordingError, match="not an MCAP|damaged|truncated") as e:
            read_recording(path)
        assert str(path) in str(e.value), pos


def test_not_a_recording(tmp_path):
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(RecordingError, match="empty"):
        read_recording(empty)
    text = tmp_path / "notes.mcap"
    text.write_text("this is a text file, not a recording\n" * 3)
    with pytest.raises(RecordingError, match="not an MCAP file: it starts with b'this is a text"):
        read_recording(text)
    with pytest.raises(RecordingError, match="no such recording"):
        read_recording(tmp_path / "missing.mcap")


def test_corrupt_message_inside_a_valid_container(tmp_path):
    path = tmp_path / "junk.mcap"
    with open(path, "wb") as f:  # a well-formed MCAP whose second payload is not protobuf
        w = RawWriter(f)
        w.start()
        cid = w.register_channel("/tf", "protobuf", register_schema(w, FrameTransforms))
        good = FrameTransforms(transforms=[_tf(T0, "world", "cup", [0, 0, 0, 0, 0, 0, 1])])
        w.add_message(cid, log_time=T0, publish_time=T0, data=good.SerializeToString())
        w.add_message(cid, log_time=T0 + 1, publish_time=T0 + 1, data=b"\xff\xff\xff\xff")
        w.finish()
    with pytest.raises(RecordingError,
                       match=r"'/tf'.*message #1 is not a valid foxglove.FrameTransforms"):
        read_recording(path)


# ------------------------------------------------------------------ bad content

def _base_msgs(t=T0):
    return [("/tf", FrameTransforms(transforms=[
        _tf(t, "world", "cup", [0, 0, 0, 0, 0, 0, 1]),
        _tf(t, "world", "cam0", [0, 0, -1, 0, 0, 0, 1])]), t)]


def _mask_msg(t=T0, width=W, height=H, topic="/camera/cam0/mask"):
    return (topic, RawImage(timestamp=_ts(t), frame_id="cam0", width=width, height=height,
                            encoding="mono8", data=bytes(width * height)), t)


@pytest.mark.parametrize("msgs, pattern", [
    ([("/cal", _calibration(), T0), _mask_msg()],
     r"no pose topic.*FrameTransforms.*topics in the file: /cal \(foxglove.CameraCalibration\)"),
    (_base_msgs() + [_mask_msg()],
     r"'/camera/cam0/mask'.*masks of camera 'cam0' have no foxglove.CameraCalibration"),
    (_base_msgs() + [("/cal", _calibration(), T0), _mask_msg(width=10, height=8)],
     r"'/camera/cam0/mask' at t=1700000000.000000000 s: mask of camera 'cam0' is 10x8 px but "
     r"its calibration is 32x24 px"),
    (_base_msgs(T0 + DT) + _base_msgs(T0),
     r"'/tf'.*timestamps go backwards for frame 'cup': 1700000000.000000000 s after "
     r"1700000000.016666667 s"),
    ([("/cal", _calibration(), T0), _mask_msg(T0 + DT), _mask_msg(T0)] + _base_msgs(),
     r"'/camera/cam0/mask'.*backwards for camera 'cam0'"),
    ([("/tf", _tf(T0, "world", "cup", [0, np.nan, 0, 0, 0, 0, 1]), T0)],
     r"'/tf' at t=.*pose of 'cup'.*not finite"),
    ([("/tf", _tf(T0, "world", "cup", [0, 0, 0, 0, 0, 0, 2]), T0)],
     r"pose of 'cup'.*quaternion norm 2"),
    ([("/scene", _spec(), T0)] + _base_msgs(),
     r"never mention scene object\(s\) \['bowl'\]; child frames seen: \['cam0', 'cup'\]"),
    (_base_msgs() + [("/cal", _calibration(model="equidistant"), T0)],
     r"'/cal'.*distortion model 'equidistant' is not supported"),
    ([("/tf", _tf(T0, "world", "table", [0, 0, 0, 0, 0, 0, 1]), T0),
      ("/tf", _tf(T0, "table", "cam0", [0, 0, 0, 0, 0, 0, 1]), T0),
      ("/cal", _calibration(), T0)],
     r"frame 'cam0' is given relative to 'table', not 'world'"),
    (_base_msgs() + [("/cal", _calibration(), T0), ("/cal", _calibration(width=64), T0)],
     r"calibration of camera 'cam0' changes"),
    (_base_msgs() + [("/cal", _calibration(), T0),
                     ("/camera/cam0/mask", RawImage(frame_id="cam0", width=W, height=H,
                                                    encoding="rgb8", data=bytes(3 * W * H)), T0)],
     r"mask encoding 'rgb8' is not supported"),
    (_base_msgs() + [("/cal", _calibration(), T0),
                     ("/camera/cam0/mask", RawImage(frame_id="cam0", width=W, height=H,
                                                    encoding="mono8", data=bytes(10)), T0)],
     r"10 data bytes do not hold 24 rows"),
    (_base_msgs() + [("/cal", _calibration(), T0),
                     ("/cam0/mask", CompressedImage(format="png", data=b"garbage"), T0)],
     r"'/cam0/mask'.*OpenCV cannot decode"),
    (_base_msgs() + [("/cal", _calibration(), T0), ("/camera/cam0/mask", CompressedImage(
        frame_id="cam0", format="tiff", data=b"II*"), T0)],
     r"compressed format 'tiff' is not supported"),
])
def test_bad_content_is_refused_with_a_useful_message(tmp_path, msgs, pattern):
    path = _user_file(tmp_path / "bad.mcap", msgs)
    with pytest.raises(RecordingError, match=pattern) as e:
        read_recording(path)
    assert str(path) in str(e.value)
    with pytest.raises(RecordingError, match=pattern):
        next(iter_messages(path))


def test_non_protobuf_pose_topic_is_refused(tmp_path):
    path = tmp_path / "json.mcap"
    with open(path, "wb") as f:
        w = RawWriter(f)
        w.start()
        sid = w.register_schema("foxglove.FrameTransforms", "jsonschema", b"{}")
        cid = w.register_channel("/tf", "json", sid)
        w.add_message(cid, log_time=0, publish_time=0, data=b'{"transforms": []}')
        w.finish()
    with pytest.raises(RecordingError, match=r"'/tf'.*schema encoding 'jsonschema' / message "
                                             r"encoding 'json' is not supported \(only protobuf\)"):
        read_recording(path)
    r = _user_file(tmp_path / "ok.mcap", _base_msgs())
    assert read_recording(r).object_names == ["cup", "cam0"]  # the same in protobuf is read


# ------------------------------------------------------------------ writer validation

def test_writer_rejects_bad_input_and_keeps_a_valid_file(tmp_path):
    rng = np.random.default_rng(8)
    cam = _camera(rng)
    good = np.array([[0, 0, 0, 0, 0, 0, 1.0], [1, 0, 0, 0, 0, 0, 1.0]])
    path = tmp_path / "w.mcap"
    with RecordingWriter(path, _spec()) as rec:
        with pytest.raises(ValueError, match="no calibration yet; call write_camera"):
            rec.write_mask("cam0", T0, np.zeros((H, W), bool))
        rec.write_camera("cam0", cam, T0)
        rec.write_poses(T0 + DT, ["cup", "bowl"], good)
        wider = CameraInfo("cam0", W + 1, H, K, D, cam.pose)
        bad_calls = [
            (lambda: rec.write_poses(T0 + 2 * DT, ["cup", "bowl"], good * np.nan), "not finite"),
            (lambda: rec.write_poses(T0 + 2 * DT, ["cup", "bowl"], good * 1.5), "quaternion norm"),
            (lambda: rec.write_poses(T0 + 2 * DT, ["cup", "bowl"], good[:1]), r"shape \(2, 7\)"),
            (lambda: rec.write_poses(T0 + 2 * DT, ["cup", "cup"], good), "repeat"),
            (lambda: rec.write_poses(T0 + 2 * DT, ["cup", "plate"], good),
             r"\['plate'\] are not in the scene"),
            (lambda: rec.write_poses(T0, ["cup", "bowl"], good),
             "/tf: timestamps must not go backwards"),
            (lambda: rec.write_poses(1.5, ["cup", "bowl"], good), "integer number of nanoseconds"),
            (lambda: rec.write_poses(-1, ["cup", "bowl"], good), r"must be in \[0, 2\*\*63\)"),
            (lambda: rec.write_mask("cam0", T0, np.zeros((W, H), bool)),
             r"shape \(32, 24\), but the camera is calibrated 32x24"),
            (lambda: rec.write_mask("cam0", T0, np.full((H, W), 0.5)), "bool array"),
            (lambda: rec.write_mask("cam0", 5, np.zeros((H, W), bool)),
             "before the recording's start"),
            (lambda: rec.write_image("cam0", T0, np.zeros((H, W, 3), np.float32)), "uint8"),
            (lambda: rec.write_image("cam0", T0, np.zeros((H, W, 3), np.uint8), "bmp"), "jpeg"),
            (lambda: rec.write_camera("cam1", cam, T0 + DT), "CameraInfo named 'cam0'"),
            (lambda: rec.write_camera("cam/0", CameraInfo("cam/0", W, H, K, D, cam.pose), T0 + DT),
             "letters, digits"),
            (lambda: rec.write_camera("cam0", wider, T0 + DT),
             "intrinsics changed"),
            (lambda: rec.write_camera("cup", CameraInfo("cup", W, H, K, D, cam.pose), T0 + DT),
             "not in the scene's cameras"),
        ]
        for call, pattern in bad_calls:
            with pytest.raises(ValueError, match=pattern):
                call()
        rec.write_mask("cam0", T0 + DT, np.ones((H, W), np.uint8))  # 0/1 integers are fine
    r = read_recording(path)
    assert np.array_equal(r.pose_times_ns, [T0 + DT]) and np.array_equal(r.poses[0], good)
    assert r.masks["cam0"][1].all() and r.masks["cam0"][1].shape == (1, H, W)
    with pytest.raises(ValueError, match="already closed"):
        rec.write_poses(T0 + 9 * DT, ["cup", "bowl"], good)


def test_camera_info_validation():
    pose = np.r_[0, 0, 0, 0, 0, 0, 1.0]
    with pytest.raises(ValueError, match="fx, fy > 0"):
        CameraInfo("c", W, H, np.diag([1.0, -1.0, 1.0]), D, pose)
    with pytest.raises(ValueError, match=r"D must have shape \(5,\)"):
        CameraInfo("c", W, H, K, D[:4], pose)
    with pytest.raises(ValueError, match="positive integer"):
        CameraInfo("c", 0, H, K, D, pose)
    with pytest.raises(ValueError, match="non-empty string"):
        CameraInfo("", W, H, K, D, pose)
    with pytest.raises(ValueError, match="not finite"):
        CameraInfo("c", W, H, K, D, np.r_[np.nan, pose[1:]])
    a = CameraInfo("c", W, H, K, D, pose)
    assert a == CameraInfo("c", W, H, K.tolist(), list(D), pose) and not a.K.flags.writeable
    assert a != a.with_pose(np.r_[1.0, pose[1:]])
