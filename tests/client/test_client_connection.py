"""Client and SessionHandle against a fake server: RPCs, errors, inputs on the wire, outputs."""

import math
import time

import numpy as np
import pytest
from client_fakes import FakeServer, free_port, particle_cloud, wait_until
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from liquidtwin_proto import (PROTOCOL_VERSION, Header, SceneObject, SceneSpec, SessionSpec,
                              TrackingMode, encode_attachment, make_header)

from liquidtwin_client import Client, ServerError, SessionHandle, decode_particles

T0 = 1_767_225_600_000_000_000
SCENE = SceneSpec(name="two cups", objects=[SceneObject(name="cup", model="cup", container=True)])
POSE = (0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1.0)


@pytest.fixture
def client(fake_server):
    with Client(connect=fake_server.endpoint) as c:
        yield c


def test_create_session_wraps_the_scene_and_names_a_live_client(fake_server, client):
    s = client.create_session(SCENE, tracking="open_loop")
    method, _, req = fake_server.requests[-1]
    assert method == "create_session"
    assert req.spec.scene == SCENE and req.spec.tracking == TrackingMode.OPEN_LOOP
    assert req.header.version == PROTOCOL_VERSION and req.session_id == ""
    assert s.session_id == "auto-0" and s.last_status.state == "running"
    # the id named in the request is the liveliness token this client declared
    alive = [str(r.ok.key_expr) for r in
             fake_server.zenoh.liveliness().get("liquidtwin/alive/clients/*", timeout=2.0)]
    assert alive == [f"liquidtwin/alive/clients/{req.client_id}"]
    # a SessionSpec goes through as is; tracking=None keeps the spec's
    spec = SessionSpec(scene=SCENE, tracking=TrackingMode.MAP_FILTER, device="cpu")
    client.create_session(spec, session_id="robot-1")
    assert fake_server.requests[-1][2].spec == spec
    assert fake_server.requests[-1][2].session_id == "robot-1"
    assert [st.session_id for st in client.list_sessions()] == ["auto-0", "robot-1"]


def test_server_errors_carry_code_name_and_message(fake_server, client):
    client.create_session(SCENE, session_id="dup")
    with pytest.raises(ServerError) as err:
        client.create_session(SCENE, session_id="dup")
    assert (err.value.code_name, err.value.message) == ("ALREADY_EXISTS",
                                                        "session 'dup' already exists")
    assert err.value.code == 7 and str(err.value).startswith("ALREADY_EXISTS: ")
    with pytest.raises(ServerError, match="UNKNOWN_SESSION: no session 'nope' here"):
        client.session("nope")
    assert client.session("dup").last_status.session_id == "dup"
    with pytest.raises(ValueError, match="contains '/'"):
        client.create_session(SCENE, session_id="a/b")
    with pytest.raises(ValueError, match="unknown tracking mode"):
        client.create_session(SCENE, tracking="psychic")


def test_no_server_is_a_timeout_that_says_what_to_start():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with Client(connect=endpoint, server_wait=0.5) as c:
        t = time.monotonic()
        with pytest.raises(TimeoutError) as err:
            c.list_sessions()
        assert time.monotonic() - t < 3.0
    assert f"no liquidtwin server answered on {endpoint} within 0.5 s" in str(err.value)
    assert "liquidtwin serve" in str(err.value)


def test_bad_endpoints_are_value_errors():
    with pytest.raises(ValueError, match="like 'tcp/127.0.0.1:7447'"):
        Client(connect="localhost")
    with pytest.raises(ValueError, match="cannot open a Zenoh session to foo/bar"):
        Client(connect="foo/bar")


def test_a_slow_create_times_out_with_the_rpc_named(fake_server, client):
    fake_server.create_delay_s = 1.5
    t = time.monotonic()
    with pytest.raises(TimeoutError, match="did not answer liquidtwin/rpc/create_session "
                                           "within 0.4 s"):
        client.create_session(SCENE, timeout=0.4)
    assert 0.35 < time.monotonic() - t < 1.4
    fake_server.create_delay_s = 1.0  # within the timeout: the late reply is taken
    assert client.create_session(SCENE, session_id="late", timeout=5.0).session_id == "late"


def test_inputs_go_out_as_foxglove_messages_with_headers(fake_server, client):
    s = client.create_session(SCENE, session_id="io")
    K = np.array([[500.0, 0, 320], [0, 510.0, 240], [0, 0, 1]])
    D = np.array([0.1, -0.05, 0.001, 0.002, 0.0])
    mask = np.zeros((4, 6), bool)
    mask[1:3, 2:5] = True
    assert s.publish_camera("cam0", K, D, 640, 480, stamp_ns=T0) == 0
    assert s.publish_mask("cam0", mask, stamp_ns=T0) == 0
    assert s.publish_mask("cam0", mask.astype(np.uint8) * 7, stamp_ns=T0 + 1) == 1
    assert s.publish_image("cam0", b"\x89PNG-ish", format="png", stamp_ns=T0) == 0
    assert s.publish_poses({"cup": POSE, "cam0": (0, 1, 0, 1, 0, 0, 0)}, stamp_ns=T0) == 0
    assert wait_until(lambda: len(fake_server.inputs) == 5)

    (h, p), = fake_server.inputs_of("camera")
    cal = CameraCalibration.FromString(p)
    assert (cal.frame_id, cal.width, cal.height, cal.distortion_model) == ("cam0", 640, 480,
                                                                           "plumb_bob")
    np.testing.assert_array_equal(np.reshape(cal.K, (3, 3)), K)
    np.testing.assert_array_equal(cal.D, D)
    np.testing.assert_array_equal(np.reshape(cal.P, (3, 4))[:, :3], K)
    np.testing.assert_array_equal(np.reshape(cal.R, (3, 3)), np.eye(3))
    assert (h.session_id, h.seq, h.stamp_ns, h.version) == ("io", 0, T0, PROTOCOL_VERSION)

    masks = fake_server.inputs_of("mask")
    assert [h.seq for h, _ in masks] == [0, 1]
    for h, p in masks:
        img = RawImage.FromString(p)
        assert (img.encoding, img.width, img.height, img.step) == ("mono8", 6, 4, 6)
        got = np.frombuffer(img.data, np.uint8).reshape(4, 6)
        np.testing.assert_array_equal(got, np.where(mask, 255, 0))
    (_, p), = fake_server.inputs_of("image")
    assert CompressedImage.FromString(p).format == "png"

    (h, p), = fake_server.inputs_of("poses")
    tfs = FrameTransforms.FromString(p).transforms
    assert [(t.parent_frame_id, t.child_frame_id) for t in tfs] == [("world", "cup"),
                                                                     ("world", "cam0")]
    t = tfs[0]
    assert (t.translation.x, t.translation.y, t.translation.z) == POSE[:3]
    assert (t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w) == POSE[3:]
    assert t.timestamp.seconds * 10**9 + t.timestamp.nanos == T0


@pytest.mark.parametrize("call, match", [
    (lambda s: s.publish_poses({"cup": (0, 0, math.nan, 0, 0, 0, 1)}), "NaN"),
    (lambda s: s.publish_poses({"cup": (0, 0, 0, 0, 0, 0.1, 1)}), "unit quaternion"),
    (lambda s: s.publish_poses({"cup": (0, 0, 0)}), r"shape \(7,\)"),
    (lambda s: s.publish_poses({}), "non-empty"),
    (lambda s: s.publish_mask("cam0", np.zeros((2, 3, 3), bool)), r"\(H, W\)"),
    (lambda s: s.publish_mask("cam0", np.zeros((2, 3), np.float32)), "bool or uint8"),
    (lambda s: s.publish_camera("cam0", np.eye(2), np.zeros(5), 4, 4), r"\(3, 3\)"),
    (lambda s: s.publish_camera("cam0", np.eye(3), np.zeros(4), 4, 4), "5 plumb_bob"),
    (lambda s: s.publish_image("cam0", b"", format="jpeg"), "non-empty"),
    (lambda s: s.publish_image("cam0", b"x", format="bmp"), "format"),
    (lambda s: s.publish_raw("particles", b"", 1), "unknown input stream"),
    (lambda s: s.publish_poses({"cup": POSE}, stamp_ns=1.5), "integer"),
])
def test_bad_inputs_are_refused_before_sending(fake_server, client, call, match):
    s = client.create_session(SCENE)
    with pytest.raises(ValueError, match=match):
        call(s)
    time.sleep(0.1)
    assert fake_server.inputs == []


def test_outputs_reach_callbacks_and_the_iterator(fake_server, client):
    s = client.create_session(SCENE, session_id="out")
    seen = []
    s.on("particles", seen.append)
    seq = [s.publish_poses({"cup": POSE}, stamp_ns=T0 + i) for i in range(3)]
    assert seq == [0, 1, 2]
    assert wait_until(lambda: len(seen) == 3)
    outs = list(s.outputs(timeout=0.5))
    assert sorted((o.stream, o.header.stamp_ns) for o in outs) == sorted(
        (st, T0 + i) for i in range(3) for st in ("particles", "volumes", "metrics"))
    for o in outs:
        assert o.header.session_id == "out" and o.received_ns > T0
        assert o.message.SerializeToString() == o.payload
        if o.stream == "metrics":
            assert o.message.input_seq == o.header.stamp_ns - T0 and math.isnan(o.message.iou)
    pos, speed = decode_particles(seen[0].message)
    i = np.arange(5, dtype=np.float32)
    np.testing.assert_array_equal(pos, np.stack([i * 0.01, np.full(5, 0.2), -i * 0.01], 1)
                                  .astype(np.float32))
    np.testing.assert_array_equal(speed, i)
    with pytest.raises(ValueError, match="unknown output stream"):
        s.on("poses", seen.append)


def test_the_output_queue_is_bounded_and_bad_samples_are_counted(fake_server, client):
    client.create_session(SCENE, session_id="q")
    s = SessionHandle(client, "q", None, queue_size=3)
    for i in range(3):
        s.publish_poses({"cup": POSE}, stamp_ns=T0 + i)
    assert wait_until(lambda: s.dropped_outputs == 6)
    assert [o.header.stamp_ns for o in s.outputs(timeout=0.2)] == [T0 + 2] * 3
    fake_server.publish_raw("q", "metrics", b"\x00", None)  # no header
    old = encode_attachment(Header(session_id="q", version=99))
    fake_server.publish_raw("q", "metrics", b"", old)  # a version we do not speak
    fake_server.publish_raw("q", "particles", b"\xff\xff", encode_attachment(make_header("q")))
    assert wait_until(lambda: s.bad_outputs == 3)
    assert s.next_output(timeout=0.2) is None


def test_session_rpcs(fake_server, client):
    with client.create_session(SCENE, session_id="rpcs") as s:
        assert s.status().session_id == "rpcs"
        assert s.reset().state == "running"
        st = s.set_pour_task("cup", "bowl", 25.0, max_angle_rad=1.2, controller="pid")
        assert (st.task.pour.source, st.task.pour.target, st.task.pour.volume_ml,
                st.task.pour.max_angle_rad, st.task.controller) == ("cup", "bowl", 25.0, 1.2, "pid")
        assert not s.cancel_task().task.HasField("pour")
        with pytest.raises(ValueError, match="positive"):
            s.set_pour_task("cup", "bowl", -1.0)
        (mesh,) = s.meshes()
        assert mesh.name == "cup" and mesh.container and mesh.vertices.shape == (3, 3)
        np.testing.assert_array_equal(mesh.faces, [[0, 1, 2]])
    methods = [(m, sid) for m, sid, _ in fake_server.requests[1:]]
    assert methods == [(m, "rpcs") for m in ("status", "reset", "set_task", "set_task",
                                            "meshes", "close")]
    assert all(r.header.session_id == "rpcs" for _, _, r in fake_server.requests[1:])
    assert fake_server.sessions["rpcs"].state == "closed"
    with pytest.raises(RuntimeError, match="closed"):
        s.publish_poses({"cup": POSE})


def test_decode_particles_reads_any_layout_and_refuses_bad_clouds():
    # speed first, a padding byte block, stride 24: decoded by field offsets
    fields = [PackedElementField(name=n, offset=o, type=PackedElementField.FLOAT32)
              for n, o in (("speed", 0), ("x", 8), ("y", 12), ("z", 16))]
    pts = np.array([[1, 2, 3], [4, 5, 6]], np.float32)
    rec = np.zeros((2, 6), np.float32)
    rec[:, 0], rec[:, 2:5] = [7, 8], pts
    pos, speed = decode_particles(PointCloud(point_stride=24, fields=fields,
                                             data=rec.tobytes()))
    np.testing.assert_array_equal(pos, pts)
    np.testing.assert_array_equal(speed, [7, 8])
    pos, speed = decode_particles(particle_cloud(0, 0.0))
    assert pos.shape == (0, 3) and speed.shape == (0,)
    with pytest.raises(ValueError, match="no field 'z'"):
        decode_particles(PointCloud(point_stride=8, fields=fields[:3], data=b""))
    with pytest.raises(ValueError, match="whole number"):
        decode_particles(PointCloud(point_stride=24, fields=fields, data=b"\x00" * 25))


def test_two_clients_each_get_only_their_sessions_outputs():
    server = FakeServer()
    try:
        with Client(connect=server.endpoint) as a, Client(connect=server.endpoint) as b:
            sa, sb = a.create_session(SCENE, session_id="a"), b.create_session(SCENE, session_id="b")
            sa.publish_poses({"cup": POSE}, stamp_ns=T0)
            sb.publish_poses({"cup": (0, 0.7, 0, 0, 0, 0, 1)}, stamp_ns=T0 + 5)
            assert wait_until(lambda: server.answered == 2)
            oa, ob = list(sa.outputs(timeout=0.3)), list(sb.outputs(timeout=0.3))
            assert {o.header.stamp_ns for o in oa} == {T0} and len(oa) == 3
            assert {o.header.stamp_ns for o in ob} == {T0 + 5} and len(ob) == 3
    finally:
        server.close()
