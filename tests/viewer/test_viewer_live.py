"""Live viewer without a browser: stream decoding, per-session buffers, the Zenoh feed
(against a fake server in this process) and the page's state after each update."""

import math
import threading
import time

import numpy as np
import pytest
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField as Field
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from live_fakes import (
    T0,
    FakeService,
    box_mesh,
    camera_msg,
    free_port,
    overlay_msg,
    particles_msg,
    poses_msg,
)
from liquidtwin_proto import (
    ContainerVolume,
    Header,
    Metrics,
    ObjectMesh,
    SceneMeshes,
    Volumes,
    encode_attachment,
    make_header,
    pack_array,
)
from viser.transforms import SO3

from liquidtwin_viewer import (
    FeedConfig,
    LiveFeed,
    Particles,
    SessionBuffer,
    StreamError,
    auto_vmax,
    decode_camera,
    decode_meshes,
    decode_overlay,
    decode_particles,
    decode_poses,
    open_zenoh,
    pose_to_viser,
    ramp,
    speed_colors,
)
from liquidtwin_viewer.colormap import RAMP
from liquidtwin_viewer.pointclouds import _rotation

RNG = np.random.default_rng(7)


# ------------------------------------------------------------------------------ decoding
def test_particles_padded_layout_pose_and_non_finite_rows():
    # stride 20: speed (f4) at 0, z (f8) at 4, x (f4) at 12, y (f4) at 16.
    pts = RNG.normal(size=(5, 3))
    speed = np.arange(5, dtype=np.float32)
    pts[2, 0] = np.nan
    rec = np.dtype({"names": ["speed", "z", "x", "y"], "formats": ["<f4", "<f8", "<f4", "<f4"],
                    "offsets": [0, 4, 12, 16], "itemsize": 20})
    data = np.zeros(5, rec)
    data["speed"], data["z"], data["x"], data["y"] = speed, pts[:, 2], pts[:, 0], pts[:, 1]
    cloud = PointCloud(frame_id="world", point_stride=20, data=data.tobytes(), fields=[
        Field(name="speed", offset=0, type=Field.FLOAT32),
        Field(name="z", offset=4, type=Field.FLOAT64),
        Field(name="x", offset=12, type=Field.FLOAT32),
        Field(name="y", offset=16, type=Field.FLOAT32)])
    cloud.pose.position.y = 1.0
    cloud.pose.orientation.w = 1.0
    got = decode_particles(cloud.SerializeToString())
    keep = [0, 1, 3, 4]
    want = pts[keep].astype(np.float32).astype(np.float64) + [0, 1, 0]
    np.testing.assert_allclose(got.points, want, atol=1e-6)
    np.testing.assert_array_equal(got.speed, speed[keep])


def test_particles_without_speed_and_errors():
    cloud = PointCloud(frame_id="world", point_stride=12,
                       data=np.ones((3, 3), "<f4").tobytes(),
                       fields=[Field(name=n, offset=4 * i, type=Field.FLOAT32)
                               for i, n in enumerate("xyz")])
    got = decode_particles(cloud.SerializeToString())
    assert got.points.shape == (3, 3) and np.isnan(got.speed).all()
    cloud.frame_id = "cam0"
    with pytest.raises(StreamError, match="frame 'cam0'"):
        decode_particles(cloud.SerializeToString())
    with pytest.raises(StreamError, match="malformed foxglove.PointCloud"):
        decode_particles(b"\xff\xff\xff")
    cloud.frame_id, cloud.point_stride = "world", 7
    with pytest.raises(StreamError, match="not a multiple of point_stride"):
        decode_particles(cloud.SerializeToString())


def test_overlay_with_row_padding_and_errors():
    img = RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    camera, got = decode_overlay(overlay_msg("cam1", img, step_pad=3).SerializeToString())
    assert camera == "cam1"
    np.testing.assert_array_equal(got, img)
    assert got.flags.c_contiguous
    with pytest.raises(StreamError, match="expected 'rgb8'"):
        decode_overlay(RawImage(width=1, height=1, encoding="mono8", data=b"\0").
                       SerializeToString())
    short = overlay_msg("cam1", img)
    short.data = short.data[:-1]
    with pytest.raises(StreamError, match="needs 105 bytes, has 104"):
        decode_overlay(short.SerializeToString())


def test_poses_normalised_other_parents_skipped():
    q = np.array([0.1, 0.2, 0.3, 0.9])
    msg = poses_msg({"cup": np.array([1, 2, 3, *(2 * q)]), "cam0": np.array([0, 0, 0, 0, 0, 0, 1])})
    msg.transforms[1].parent_frame_id = "table"
    got = decode_poses(msg.SerializeToString())
    assert list(got) == ["cup"]
    np.testing.assert_allclose(got["cup"], [1, 2, 3, *(q / np.linalg.norm(q))])
    bad = poses_msg({"cup": np.array([np.nan, 0, 0, 0, 0, 0, 1])})
    with pytest.raises(StreamError, match="'cup' is not finite"):
        decode_poses(bad.SerializeToString())
    with pytest.raises(StreamError, match="zero"):
        decode_poses(poses_msg({"cup": np.zeros(7)}).SerializeToString())


def test_camera_fov_matches_the_angle_between_edge_rays():
    cal = camera_msg("cam0", 640, 480, 500.0)
    cal.K[4], cal.K[5] = 520.0, 250.0  # fy, and a principal point off centre (cy)
    cam = decode_camera(cal.SerializeToString())
    assert (cam.name, cam.width, cam.height, cam.aspect) == ("cam0", 640, 480, 640 / 480)
    # Independent: the vertical fov the frustum draws is symmetric, 2 atan(h / 2 fy); check
    # it against the angle between back-projected rays through rows 0 and h of a centred K.
    kc = np.array([[500.0, 0, 320], [0, 520, 240], [0, 0, 1]])
    top, bottom = np.linalg.solve(kc, [320, 0, 1]), np.linalg.solve(kc, [320, 480, 1])
    angle = math.acos(top @ bottom / np.linalg.norm(top) / np.linalg.norm(bottom))
    assert cam.fov_y == pytest.approx(angle, rel=1e-12)
    cal.K[0] = 0.0
    with pytest.raises(StreamError, match="focal lengths must be positive"):
        decode_camera(cal.SerializeToString())


def test_meshes_round_trip_and_bad_indices():
    msg = SceneMeshes(objects=[box_mesh((0.1, 0.2, 0.3), "cup", True)])
    (mesh,) = decode_meshes(msg.SerializeToString())
    assert mesh.name == "cup" and mesh.container and mesh.faces.shape == (12, 3)
    np.testing.assert_allclose(mesh.vertices.max(axis=0), [0.1, 0.4, 0.3], rtol=1e-6)
    bad = SceneMeshes(objects=[ObjectMesh(name="x", vertices=pack_array(np.zeros((3, 3))),
                                          faces=pack_array(np.array([[0, 1, 3]], np.uint32)))])
    with pytest.raises(StreamError, match="face index out of range 0..2"):
        decode_meshes(bad.SerializeToString())


# ----------------------------------------------------------------------------- colouring
def test_speed_colors_follow_the_ramp():
    c = speed_colors(np.array([0.0, 1.0, 2.0, 4.0, 99.0, np.nan]), vmax=4.0)
    np.testing.assert_array_equal(c[[0, 3, 4, 5]], RAMP[[0, -1, -1, 0]].astype(np.uint8))
    np.testing.assert_array_equal(c[1], RAMP[1])
    np.testing.assert_array_equal(c[2], RAMP[2])
    # Halfway between two stops is their mean (rounded).
    np.testing.assert_array_equal(ramp(np.array([0.125])), [np.rint((RAMP[0] + RAMP[1]) / 2)])
    with pytest.raises(ValueError, match="positive"):
        speed_colors(np.ones(2), 0.0)


def test_auto_vmax_rises_at_once_and_falls_slowly():
    fast = np.linspace(0, 2.0, 1001)
    assert auto_vmax(fast) == pytest.approx(np.percentile(fast, 99))
    assert auto_vmax(np.zeros(10)) == 0.05
    v = auto_vmax(np.zeros(10), previous=1.0)
    assert v == pytest.approx(0.9 + 0.1 * 0.05)
    assert auto_vmax(fast, previous=0.1) == pytest.approx(1.98)


def test_pose_to_viser_gives_the_same_rotation_as_the_xyzw_formula():
    q = RNG.normal(size=4)
    q /= np.linalg.norm(q)
    position, wxyz = pose_to_viser(np.array([1, 2, 3, *q]))
    np.testing.assert_array_equal(position, [1, 2, 3])
    np.testing.assert_allclose(SO3(wxyz).as_matrix(), _rotation(_Q(*q)), atol=1e-12)


class _Q:
    def __init__(self, x, y, z, w):
        self.x, self.y, self.z, self.w = x, y, z, w


# ------------------------------------------------------------------------------- buffers
def _particles(n=4, value=0.0):
    return Particles(np.full((n, 3), value, np.float32), np.zeros(n, np.float32))


def test_buffer_fps_window_and_snapshot_isolation():
    buf = SessionBuffer("s", window_s=1.0)
    for i in range(61):  # 30 frames/s for 2 s of receive time
        buf.add_particles(T0 + i * 33_333_333, _particles(value=i), rx_s=100 + i / 30)
    snap = buf.snapshot(now_s=100 + 2.0)
    assert snap.frames == 61 and snap.fps == pytest.approx(30.0, rel=1e-6)
    assert snap.age_s == pytest.approx(0.0, abs=1e-9)
    assert snap.particles.points[0, 0] == 60
    for i in range(25):  # 0.1 s apart: a 1 s window keeps the last 11
        buf.add_metrics(T0 + i * 100_000_000, Metrics(iou=i / 100))
    buf.add_particles(T0, _particles(value=-1), rx_s=103.0)
    later = buf.snapshot(now_s=103.5)
    assert snap.particles.points[0, 0] == 60 and later.particles.points[0, 0] == -1
    np.testing.assert_allclose(later.iou.t, np.arange(-10, 1) / 10)
    np.testing.assert_allclose(later.iou.values["iou"], np.arange(14, 25) / 100)
    # The 2 s rate window at 103.5 s holds 16 frames from 101.5..102 s and the one at 103 s.
    assert later.fps == pytest.approx(16 / 1.5) and later.age_s == pytest.approx(0.5)
    assert buf.snapshot(now_s=105.5).fps == 0.0
    assert later.version > snap.version


def test_buffer_merges_poses_and_volume_columns():
    buf = SessionBuffer("s")
    buf.add_poses({"cup": np.zeros(7), "cam": np.ones(7)})
    buf.add_poses({"cup": np.full(7, 2.0)})
    buf.add_volumes(T0, {"cup": 10.0})
    buf.add_volumes(T0 + 10**9, {"cup": 9.0, "bowl": 1.0})
    snap = buf.snapshot()
    assert snap.poses["cup"][0] == 2.0 and snap.poses["cam"][0] == 1.0
    np.testing.assert_array_equal(snap.volumes.t, [-1.0, 0.0])
    np.testing.assert_array_equal(snap.volumes.values["cup"], [10.0, 9.0])
    np.testing.assert_array_equal(snap.volumes.values["bowl"], [np.nan, 1.0])


def test_buffer_is_consistent_under_concurrent_writers():
    buf = SessionBuffer("s")
    stop, seen = threading.Event(), []

    def write(k):
        for i in range(300):
            buf.add_particles(T0 + i, _particles(value=k))
            buf.add_metrics(T0 + i, Metrics(iou=0.5))

    def read():
        while not stop.is_set():
            snap = buf.snapshot()
            seen.append(snap.frames)
            assert len(snap.iou.t) == len(snap.iou.values.get("iou", ()))

    reader = threading.Thread(target=read)
    reader.start()
    writers = [threading.Thread(target=write, args=(k,)) for k in range(4)]
    for w in writers:
        w.start()
    for w in writers:
        w.join()
    stop.set()
    reader.join()
    assert buf.snapshot().frames == 1200
    assert seen == sorted(seen)  # frames never go backwards


# --------------------------------------------------------------------------------- feed
def _sample(session, stream, msg, stamp=T0, direction="out", header=None):
    key = f"liquidtwin/{session}/{direction}/{stream}"
    header = header if header is not None else make_header(session, 0, stamp)
    return key, msg.SerializeToString(), encode_attachment(header)


def test_feed_routes_samples_and_rejects_bad_headers():
    feed = LiveFeed()
    pts = RNG.normal(size=(10, 3)).astype(np.float32)
    feed.handle_sample(*_sample("a", "particles", particles_msg(pts, np.ones(10))))
    feed.handle_sample(*_sample("b", "volumes", Volumes(containers=[
        ContainerVolume(name="cup", ml=5.0)]), stamp=T0 + 5))
    feed.handle_sample(*_sample("b", "poses", poses_msg({"cup": np.r_[1, 2, 3, 0, 0, 0, 1.0]}),
                                direction="in"))
    feed.handle_sample(*_sample("b", "camera", camera_msg("cam0", 64, 48, 50.0),
                                direction="in"))
    feed.handle_sample("other/a/out/particles", b"", None)  # not our prefix: ignored
    feed.handle_sample("liquidtwin/c/in/mask", b"", None)  # a stream the viewer skips
    assert feed.sessions() == ["a", "b"]
    a, b = feed.snapshot("a"), feed.snapshot("b")
    np.testing.assert_array_equal(a.particles.points, pts)
    assert a.particles_stamp_ns == T0 and a.rejected == 0
    assert b.volumes.values["cup"].tolist() == [5.0] and b.poses["cup"][2] == 3.0
    assert b.cameras["cam0"].width == 64
    key, payload, _ = _sample("a", "metrics", Metrics())
    feed.handle_sample(key, payload, None)
    feed.handle_sample(key, payload, encode_attachment(Header(session_id="a", version=99)))
    feed.handle_sample(key, payload, encode_attachment(make_header("b")))
    feed.handle_sample(*_sample("a", "overlay", RawImage(encoding="bgr8")))
    a = feed.snapshot("a")
    assert a.rejected == 4 and a.metrics is None and a.overlay is None
    assert "overlay" in a.last_error and "'rgb8'" in a.last_error


def test_feed_over_zenoh_lists_sessions_fetches_meshes_and_buffers_streams():
    port = free_port()
    server = open_zenoh(listen=f"tcp/127.0.0.1:{port}")
    viewer = open_zenoh(connect=f"tcp/127.0.0.1:{port}")
    fake = FakeService(server, sessions=["demo", "idle"],
                       meshes={"demo": [box_mesh((0.04, 0.05, 0.04), "cup", True)]})
    feed = LiveFeed(viewer, FeedConfig(poll_s=0.2, rpc_timeout_s=1.0)).start()
    try:
        deadline = time.monotonic() + 10
        snap = feed.snapshot("demo")
        i = 0
        # Each stream has its own subscriber: a frame's particles can be counted before its
        # metrics or overlay arrive (or before their subscribers were declared), so wait for all.
        while time.monotonic() < deadline and (snap.frames < 3 or snap.meshes is None or len(snap.iou.t) < 3
                                               or snap.overlay is None):
            fake.frame("demo", i, n=500)
            i += 1
            time.sleep(0.05)
            snap = feed.snapshot("demo")
        assert snap.frames >= 3 and snap.meshes is not None, fake.queries
        assert [m.name for m in snap.meshes] == ["cup"]
        assert feed.sessions() == ["demo", "idle"] and feed.status("idle").state == "running"
        assert snap.particles.points.shape == (500, 3) and snap.overlay.shape == (120, 160, 3)
        assert set(snap.poses) == {"cup", "target", "cam0"} and "cam0" in snap.cameras
        assert snap.rejected == 0 and len(snap.iou.t) >= 3
    finally:
        feed.close()
        fake.close()
        viewer.close()
        server.close()


# --------------------------------------------------------------------------------- page
def test_page_draws_selected_session_and_pause_freezes_it():
    from liquidtwin_viewer.live import LiveViewer

    feed = LiveFeed()
    page = LiveViewer(feed, port=free_port(), session="b", run_thread=False)
    try:
        page.render_once()
        assert page.selected is None
        assert page.panel.session_menu.options == ("(waiting for sessions)",)
        pts = RNG.normal(size=(20, 3)).astype(np.float32)
        for sid in ("a", "b"):
            feed.handle_sample(*_sample(sid, "particles", particles_msg(pts, np.ones(20))))
        feed.buffer("b").set_meshes(decode_meshes(SceneMeshes(
            objects=[box_mesh((0.1, 0.1, 0.1), "cup", True)]).SerializeToString()))
        pose = np.r_[0.5, 0.0, -0.2, 0.0, 0.0, np.sin(0.3), np.cos(0.3)]
        feed.handle_sample(*_sample("b", "poses", poses_msg({"cup": pose}), direction="in"))
        page._sessions_at = -1e9
        page.render_once()
        assert page.selected == "b" and page.panel.session_menu.options == ("a", "b")
        np.testing.assert_array_equal(page._cloud.points, pts)
        cup = page._mesh_handles["cup"]
        np.testing.assert_allclose(cup.position, pose[:3])
        np.testing.assert_allclose(cup.wxyz, [pose[6], *pose[3:6]])
        assert cup.visible
        page.set_paused(True)
        feed.handle_sample(*_sample("b", "particles", particles_msg(pts + 1, np.ones(20))))
        page.render_once()
        np.testing.assert_array_equal(page._cloud.points, pts)  # frozen
        assert feed.snapshot("b").frames == 2  # still buffered
        page.set_paused(False)
        page.render_once()
        np.testing.assert_array_equal(page._cloud.points, pts + 1)
        assert page.panel.pause_button.label == "pause"
        # Choosing another session in the menu: its cloud, none of b's meshes.
        feed.handle_sample(*_sample("a", "particles", particles_msg(pts - 1, np.ones(20))))
        page._request("a")
        page.render_once()
        assert page.selected == "a" and page._mesh_handles == {}
        np.testing.assert_array_equal(page._cloud.points, pts - 1)
    finally:
        page.stop()
