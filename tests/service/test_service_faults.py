"""Hypothesis fuzzing of a real ``liquidtwin serve``: random bytes and structurally broken
messages on every RPC key and every input stream (wrong versions, NaN, non-unit quaternions,
wrong image sizes and encodings, unknown names and sessions, oversized payloads). The server
must answer every RPC with a well-formed reply or Error, count refused inputs, and stay up;
afterwards the fuzzed session still streams, and a session that streamed all along got
exactly the particles an engine fed the same frames in this process computes."""

from __future__ import annotations

import math
import threading

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from liquidtwin.session import SessionEngine
from liquidtwin_proto import liquidtwin_pb2 as pb
from zraw import (CAM_POSE, H, W, Peer, camera_msg, cloud_arrays, cup_spec, header, mask_msg, poses_msg)

E = pb.Error
CODES = set(E.Code.values()) - {E.CODE_UNSPECIFIED}
T0 = 1_700_000_000_000_000_000
DT_NS = 33_333_333
T_END = T0 + 10**13                  # after every fuzzed stamp
MAX_PAYLOAD = 60_000                 # --max-payload-mb below, bytes (rounded)
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
TARGET, VICTIM = "fuzzed", "victim"
UP = [0, 0, 0, 0, 0, 0, 1]


def _tilt(i: int) -> list:
    a = 0.25 * math.sin(i / 5)
    return [0, 0, 0, 0, 0, math.sin(a / 2), math.cos(a / 2)]


class Victim(threading.Thread):
    """Streams lockstep frames to its own session from its own Zenoh peer until stopped."""

    def __init__(self, endpoint):
        super().__init__(daemon=True)
        self.peer = Peer(endpoint)
        self.peer.create(VICTIM, cup_spec())
        self.peer.watch(VICTIM)
        self.stop, self.stamps, self.error = threading.Event(), [], None

    def run(self):
        try:
            i = 0
            while not self.stop.is_set() or i < 5:
                stamp = T0 + i * DT_NS
                self.peer.send(VICTIM, "poses", poses_msg({"cup": _tilt(i)}), stamp)
                self.peer.wait_output(VICTIM, "particles", stamp, timeout=30)
                self.peer.wait_output(VICTIM, "metrics", stamp, timeout=30)
                self.stamps.append(stamp)
                i += 1
        except Exception as exc:  # noqa: BLE001
            self.error = exc


@pytest.fixture(scope="module")
def srv(module_servers):
    proc = module_servers.start("--max-payload-mb", str(MAX_PAYLOAD / 1024 / 1024), "--max-sessions", "6")
    peer = module_servers.peer(proc)
    peer.create(TARGET, cup_spec())
    peer.send(TARGET, "camera", camera_msg(), T0)
    victim = Victim(proc.endpoint)
    module_servers.peers.append(victim.peer)
    victim.start()
    yield proc, peer, victim
    victim.stop.set()


def _check_reply(kind, body, reply_cls=None):
    assert kind in ("ok", "err"), (kind, body)
    if kind == "err":
        assert body.code in CODES and body.message, body
    elif reply_cls is not None:
        reply_cls.FromString(body)


RPC_KEYS = ["rpc/create_session", "rpc/list_sessions", "rpc/nope", f"{TARGET}/rpc/status", f"{TARGET}/rpc/reset",
            f"{TARGET}/rpc/set_task", f"{TARGET}/rpc/meshes", f"{TARGET}/rpc/close", "ghost/rpc/status"]


@FUZZ
@given(key=st.sampled_from(RPC_KEYS), payload=st.binary(max_size=3000))
def test_random_bytes_on_every_rpc(srv, key, payload):
    _, peer, _ = srv
    kind, body = peer.query(key, payload)
    _check_reply(kind, body)
    if kind == "ok" and key.endswith("close"):          # astronomically unlikely; keep the module going
        pytest.fail("random bytes closed a session")


def _valid_requests():
    task = pb.Task()
    task.pour.source, task.pour.target, task.pour.volume_ml = "cup", "cup", 1.0
    return [(f"{TARGET}/rpc/status", pb.SessionRequest(header=header(TARGET)).SerializeToString()),
            (f"{TARGET}/rpc/set_task", pb.SetTaskRequest(header=header(TARGET), task=task).SerializeToString()),
            ("rpc/list_sessions", pb.ListSessionsRequest(header=header()).SerializeToString())]


@FUZZ
@given(which=st.integers(0, 2), edits=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=6),
       cut=st.integers(0, 400), version=st.sampled_from([0, 1, 2, 2**32 - 1]))
def test_mutated_valid_requests(srv, which, edits, cut, version):
    _, peer, _ = srv
    key, raw = _valid_requests()[which]
    if version != 1:
        req = (pb.ListSessionsRequest if key.startswith("rpc/") else pb.SessionRequest)(
            header=header(version=version))
        raw = req.SerializeToString()
    b = bytearray(raw)
    for pos, val in edits:
        b[pos % len(b)] = val
    b = bytes(b[:max(1, len(b) - cut % (len(b) + 1))])
    kind, body = peer.query(key, b)
    _check_reply(kind, body)
    if version not in (1,) and not edits and cut % (len(raw) + 1) == 0:
        assert kind == "err" and body.code == E.UNSUPPORTED_VERSION


floats = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1, 1))


@st.composite
def specs(draw):
    """Session specs with every field a little wrong — but never a huge scene."""
    spec = cup_spec()
    o = spec.scene.objects[0]
    o.name = draw(st.sampled_from(["cup", "", "a/b", "x" * 70, "world"]))
    o.model = draw(st.sampled_from(["cup", "bowl", "teapot", "", "mesh"]))
    if draw(st.booleans()):
        del o.initial_pose[:]
        o.initial_pose.extend(draw(st.lists(floats, max_size=9)))
    f = spec.scene.fills[0]
    f.container = draw(st.sampled_from(["cup", "bowl", ""]))
    f.fraction = draw(st.one_of(st.floats(-1, 0.3), st.sampled_from([math.nan, math.inf, 0.0])))
    sim = spec.scene.simulation
    sim.h = draw(st.sampled_from([0.02, 0.03, -0.02, math.nan, math.inf]))
    sim.dt = draw(st.sampled_from([1 / 60, 0.0, -1.0, math.nan]))
    sim.spacing = draw(st.sampled_from([0.0, 0.012, -1.0, math.nan]))
    spec.tracking = draw(st.integers(0, 9))
    spec.device = draw(st.sampled_from(["", "cpu", "cuda", "tpu", "cuda:9"]))
    spec.correction_gain = draw(floats)
    if draw(st.booleans()):
        spec.fluid.lambda_c = draw(floats)
    if draw(st.booleans()):
        spec.pose_filter.position_noise_m = draw(floats)
        spec.pose_filter.angular_acceleration_rad_s2 = draw(floats)
    if draw(st.booleans()):
        cam = spec.cameras.add(name=draw(st.sampled_from(["cam0", "", "c/d"])), width=draw(st.integers(0, 5000)),
                               height=draw(st.integers(0, 5000)))
        cam.k.extend(draw(st.lists(floats, max_size=10)))
        cam.d.extend(draw(st.lists(floats, max_size=6)))
        cam.pose.extend(draw(st.lists(floats, max_size=8)))
    return spec


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(spec=specs(), version=st.sampled_from([1, 1, 1, 0, 3]))
def test_broken_session_specs(srv, spec, version):
    _, peer, _ = srv
    req = pb.CreateSessionRequest(header=header(version=version), session_id="fz", spec=spec)
    kind, body = peer.query("rpc/create_session", req.SerializeToString(), timeout=60)
    _check_reply(kind, body, pb.SessionStatus)
    if version != 1:
        assert body.code == E.UNSUPPORTED_VERSION
    if kind == "ok":
        peer.session_rpc("fz", "close")


attachments = st.one_of(
    st.none(), st.binary(max_size=64),
    st.builds(lambda v, s, t: header(s, 0, t, version=v).SerializeToString(),
              st.sampled_from([0, 1, 1, 2]), st.sampled_from([TARGET, "", "other", "ghost"]),
              st.integers(-10, T0 + 10**9)))


@FUZZ
@given(stream=st.sampled_from(["poses", "camera", "mask", "image"]), payload=st.binary(max_size=4000),
       attachment=attachments, session=st.sampled_from([TARGET, TARGET, "ghost"]))
def test_random_bytes_on_every_input_stream(srv, stream, payload, attachment, session):
    _, peer, _ = srv
    peer.put(session, stream, payload, attachment)


def _png(h, w):
    ok, buf = cv2.imencode(".png", np.full((h, w, 3), 128, np.uint8))
    return buf.tobytes()


@st.composite
def inputs(draw):
    """(stream, Foxglove message bytes) with structural faults."""
    stream = draw(st.sampled_from(["poses", "camera", "mask", "image", "oversized"]))
    if stream == "poses":
        names = draw(st.lists(st.sampled_from(["cup", "cam0", "teapot", "", "cup"]), min_size=0, max_size=3))
        poses = {n: draw(st.lists(floats, min_size=7, max_size=7)) for n in names}
        if draw(st.booleans()):       # well-formed but wild: far away, fast, tumbling
            q = np.array(draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4))) + [0, 0, 0, 1e-3]
            t = draw(st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=3))
            poses = {"cup": [*t, *(q / np.linalg.norm(q))]}
        msg = poses_msg(poses)
        if draw(st.booleans()) and len(msg.transforms):
            msg.transforms[0].parent_frame_id = draw(st.sampled_from(["map", ""]))
        return stream, msg.SerializeToString()
    if stream == "camera":
        k = draw(st.lists(floats, min_size=0, max_size=10))
        m = camera_msg(draw(st.sampled_from(["cam0", "cam1", "", "cup"])), draw(st.integers(0, 20000)),
                       draw(st.integers(0, 20000)), np.eye(3))
        del m.K[:]
        m.K.extend(k)
        return stream, m.SerializeToString()
    if stream == "mask":
        h, w = draw(st.sampled_from([(H, W), (H + 1, W), (H, W - 1), (1, 1)]))
        m = mask_msg(np.ones((h, w), bool), camera=draw(st.sampled_from(["cam0", "cam1", "cup"])),
                     encoding=draw(st.sampled_from(["mono8", "mono8", "rgb8", "16UC1"])))
        if draw(st.booleans()):
            m.data = m.data[:draw(st.integers(0, len(m.data)))]
            m.step = draw(st.integers(0, 2 * W))
        return stream, m.SerializeToString()
    if stream == "image":
        from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
        data = draw(st.one_of(st.binary(max_size=200), st.builds(_png, st.sampled_from([H, 7]),
                                                                     st.sampled_from([W, 9]))))
        return stream, CompressedImage(frame_id=draw(st.sampled_from(["cam0", "cam1"])), data=data,
                                       format=draw(st.sampled_from(["png", "jpeg", "bmp", ""]))).SerializeToString()
    return "poses", b"\x0a" + b"\x00" * (MAX_PAYLOAD + 100)


@FUZZ
@given(item=inputs(), stamp=st.integers(1, T_END - 1))
def test_structurally_broken_inputs(srv, item, stamp):
    _, peer, _ = srv
    stream, payload = item
    peer.put(TARGET, stream, payload, header(TARGET, 0, stamp).SerializeToString())


def test_after_the_fuzz_the_server_serves_and_the_bystander_was_untouched(srv):
    proc, peer, victim = srv
    assert proc.alive()
    peer.session_rpc(TARGET, "reset")                  # the fuzz may have driven it anywhere
    peer.watch(TARGET)
    mask = np.zeros((H, W), bool)
    mask[50:70, 70:90] = True
    for i in range(3):
        stamp = T_END + i * DT_NS
        peer.send(TARGET, "mask", mask_msg(mask), stamp)
        peer.send(TARGET, "poses", poses_msg({"cup": UP, "cam0": CAM_POSE}), stamp)
        pos, _ = cloud_arrays(peer.wait_output(TARGET, "particles", stamp, timeout=20))
        assert np.isfinite(pos).all() and len(pos) > 0
    m = peer.wait_output(TARGET, "metrics", T_END + 2 * DT_NS)
    print(f"fuzzed session: {m.rejected} inputs rejected, {m.dropped_out_of_order} out of order, "
          f"{m.frames_done} frames done; server log has "
          f"{proc.stderr().count('rejected')} rate-limited reject lines")
    assert m.rejected > 50 and m.iou == m.iou and peer.session_rpc(TARGET, "status").state == "running"

    victim.stop.set()
    victim.join(60)
    assert victim.error is None, victim.error
    vm = [mm for _, mm in victim.peer.of(VICTIM, "metrics")]
    n = len(victim.stamps)
    assert n >= 5 and vm[-1].frames_done == n and vm[-1].rejected == vm[-1].dropped_stale == 0
    # the bystander's particles equal an engine fed the same frames here, bit for bit
    engine = SessionEngine.create(cup_spec())
    clouds = {h.stamp_ns: m for h, m in victim.peer.of(VICTIM, "particles")}
    for i, stamp in enumerate(victim.stamps):
        engine.advance((stamp - T0) / 1e9, {"cup": np.array(_tilt(i))}, max_steps=8)
        if i in (0, n // 2, n - 1):
            pos, speed = cloud_arrays(clouds[stamp])
            np.testing.assert_array_equal(pos, engine.positions())
            np.testing.assert_array_equal(speed, engine.speeds())
    print(f"bystander: {n} frames streamed during the fuzz, all answered, identical to the in-process engine")


class _BuggyEngine:
    """A stand-in engine (the SessionEngine API) that crashes on a frame naming x > 100 m."""

    object_names, container_names, camera_names, n_particles, dt = ("cup",), ("cup",), set(), 3, 0.01

    def __init__(self, spec, device="cpu"):
        self.spec, self.sim_time_s, self.x = spec, 0.0, np.zeros((3, 3), np.float32)

    def camera_size(self, name):
        return None

    def advance(self, t_s, poses, *, max_steps=8):
        from liquidtwin.session import FrameResult
        if poses["cup"][0] > 100:
            raise ZeroDivisionError("a bug in the engine")
        self.sim_time_s = t_s
        self.x[:] = poses["cup"][:3]
        return FrameResult(1, 0.1, 0.0, t_s)

    def positions(self):
        return self.x.copy()

    def speeds(self):
        return np.zeros(3, np.float32)

    def volumes(self):
        return {"cup": 1.0}

    def mask_volumes(self):
        return {}

    def control(self):
        return None

    def reset(self):
        self.sim_time_s = 0.0

    def state_dict(self):
        return {"x": self.x.tolist(), "t": self.sim_time_s}


def test_an_engine_bug_fails_only_its_session_and_reset_revives_it(tmp_path):
    from liquidtwin.service import ServeConfig, Server
    from zraw import free_port, wait_until

    cfg = ServeConfig(listen=[f"tcp/127.0.0.1:{free_port()}"], state_dir=tmp_path / "state")
    server = Server(cfg, engine_factory=_BuggyEngine)
    server.start()
    peer = Peer(cfg.listen[0])
    try:
        for sid in ("buggy", "fine"):
            peer.create(sid, cup_spec())
            peer.watch(sid)
        for i, x in enumerate([0.0, 500.0, 1.0]):
            stamp = T0 + i * DT_NS
            peer.send("fine", "poses", poses_msg({"cup": [x / 100, 0, 0, 0, 0, 0, 1]}), stamp)
            peer.send("buggy", "poses", poses_msg({"cup": [x, 0, 0, 0, 0, 0, 1]}), stamp)
            peer.wait_output("fine", "metrics", stamp)
            if i == 0:
                peer.wait_output("buggy", "metrics", stamp)
            if i == 1:
                wait_until(lambda: peer.session_rpc("buggy", "status").state == "failed", 10)
        assert [round(float(cloud_arrays(m)[0][0, 0])) for _, m in peer.of("fine", "particles")] == [0, 5, 0]
        assert len(peer.of("buggy", "particles")) == 1               # nothing after the crash
        status = peer.session_rpc("buggy", "status")
        assert status.state == "failed" and peer.session_rpc("fine", "status").state == "running"
        assert peer.session_rpc("buggy", "reset").state == "running"
        peer.send("buggy", "poses", poses_msg({"cup": [2.0, 0, 0, 0, 0, 0, 1]}), T0 + 10 * DT_NS)
        m = peer.wait_output("buggy", "metrics", T0 + 10 * DT_NS)
        assert m.frames_done == 2 and m.sim_time_s == 0.0
    finally:
        peer.close()
        server.stop()
