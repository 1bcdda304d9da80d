"""Every RPC of docs/service.md against a real ``liquidtwin serve`` over raw Zenoh: happy
paths, the outputs of streamed frames (checked against an independent projection of the
published particles and the mask we sent), and every error code the wire can reach."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from liquidtwin_proto import liquidtwin_pb2 as pb
from zraw import (CAM_POSE, H, K, W, camera_msg, cloud_arrays, cup_spec, header, mask_msg, poses_msg, pour_spec)

E = pb.Error
UP = [0, 0, 0, 0, 0, 0, 1]
T0 = 1_700_000_000_000_000_000
DT_NS = 33_333_333


@pytest.fixture(scope="module")
def srv(module_servers):
    proc = module_servers.start("--max-payload-mb", "0.25", "--max-sessions", "3", "--checkpoint-s", "0.2")
    peer = module_servers.peer(proc)
    yield proc, peer
    assert proc.alive(), proc.stderr()[-3000:]


def _quat_matrix(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _project(points):
    """Pixel coordinates (N, 2) of world points seen by cam0 (pinhole, no distortion)."""
    cam = (points - CAM_POSE[:3]) @ _quat_matrix(CAM_POSE[3:])
    return np.stack([K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2], K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]], 1)


def test_create_list_status_meshes_close(srv):
    proc, peer = srv
    st = peer.create("rpc-a", cup_spec())
    assert (st.session_id, st.state, st.restored) == ("rpc-a", "running", False)
    assert st.particles > 50 and st.server_id in proc.ready_line
    assert [v.name for v in st.volumes] == ["cup"] and st.volumes[0].ml > 0
    d = proc.state_dir / "sessions" / "rpc-a"
    assert pb.SessionSpec.FromString((d / "spec.pb").read_bytes()) == st.spec == cup_spec()
    assert json.loads((d / "meta.json").read_text())["state"] == "open"
    assert st.log_path.endswith("log-0000.mcap")

    listed = peer.list_sessions()
    assert listed.server_id == st.server_id and "rpc-a" in [s.session_id for s in listed.sessions]
    assert peer.session_rpc("rpc-a", "status").particles == st.particles

    meshes = peer.session_rpc("rpc-a", "meshes")
    (obj,) = meshes.objects
    v = np.frombuffer(obj.vertices.data, obj.vertices.dtype).reshape(tuple(obj.vertices.shape))
    f = np.frombuffer(obj.faces.data, obj.faces.dtype).reshape(tuple(obj.faces.shape))
    assert obj.name == "cup" and obj.container and v.shape[1] == 3 and f.shape[1] == 3
    assert f.max() < len(v) and v[:, 1].min() > -1e-3    # the cup stands on y = 0, opening up

    closed = peer.session_rpc("rpc-a", "close")
    assert closed.state == "closed"
    assert json.loads((d / "meta.json").read_text())["state"] == "closed"
    assert peer.error("rpc-a/rpc/status", pb.SessionRequest(header=header("rpc-a")).SerializeToString()).code \
        == E.UNKNOWN_SESSION
    assert "rpc-a" not in [s.session_id for s in peer.list_sessions().sessions]


def test_frames_get_particles_volumes_metrics_and_overlay(srv):
    _, peer = srv
    sid = "rpc-frames"
    st = peer.create(sid, cup_spec())
    peer.watch(sid)
    peer.send(sid, "camera", camera_msg(), T0)
    mask = np.zeros((H, W), bool)
    mask[50:70, 70:90] = True
    seqs = []
    for i in range(6):
        stamp = T0 + i * DT_NS
        if i % 2 == 0:
            peer.send(sid, "mask", mask_msg(mask), stamp)
        seqs.append(peer.send(sid, "poses", poses_msg({"cup": UP, "cam0": CAM_POSE}), stamp))
        peer.wait_output(sid, "metrics", stamp)          # lockstep: every frame is processed
    metrics = [m for _, m in peer.of(sid, "metrics")]
    assert [m.input_seq for m in metrics] == seqs
    assert [m.frames_done for m in metrics] == [1, 2, 3, 4, 5, 6]
    assert all(m.rejected == m.dropped_stale == m.dropped_out_of_order == 0 for m in metrics)
    assert [round(m.sim_time_s * 60) for m in metrics] == [0, 2, 4, 6, 8, 10]   # dt 1/60, frames 1/30 s
    assert all(m.particles == st.particles and m.lag_ms >= 0 and m.sim_lag_s == 0 for m in metrics)
    assert all(math.isnan(m.iou) == (i % 2 == 1) for i, m in enumerate(metrics))

    clouds = peer.of(sid, "particles")
    assert [h.stamp_ns for h, _ in clouds] == [T0 + i * DT_NS for i in range(6)]
    assert [h.seq for h, _ in clouds] == list(range(6)) and all(h.session_id == sid for h, _ in clouds)
    pos, speed = cloud_arrays(clouds[-1][1])
    assert pos.shape == (st.particles, 3) and np.isfinite(pos).all() and (speed >= 0).all()
    assert pos[:, 1].min() > -0.01 and np.abs(pos[:, [0, 2]]).max() < 0.06     # still in the cup

    overlays = peer.of(sid, "overlay")
    assert [h.stamp_ns for h, _ in overlays] == [T0 + i * DT_NS for i in (0, 2, 4)]
    img_h, img = overlays[-1]
    info = metrics[4].overlay
    rgb = np.frombuffer(img.data, np.uint8).reshape(H, W, 3)
    blue, green, yellow = ((rgb == c).all(-1) for c in ((0, 0, 255), (0, 255, 0), (255, 255, 0)))
    np.testing.assert_array_equal(blue | yellow, mask)          # exactly the mask we sent
    assert (info.observed_px, info.model_px, info.overlap_px) == (mask.sum(), (green | yellow).sum(), yellow.sum())
    assert info.camera == "cam0" and img.encoding == "rgb8" and metrics[4].iou == pytest.approx(
        yellow.sum() / (blue | green | yellow).sum())
    # every model pixel lies within the disc radius (5 px) of a particle we were sent, projected by us
    uv = _project(cloud_arrays(clouds[4][1])[0].astype(np.float64))      # the masked frame's particles
    model_px = np.argwhere(green | yellow)[:, ::-1] + 0.5
    assert len(model_px) > 0
    near = np.sqrt(((model_px[:, None, :] - uv[None]) ** 2).sum(-1)).min(1)
    assert near.max() <= 5.0 + 1.5     # radius + a pixel diagonal (particles are binned to pixels, then dilated)

    vols = peer.of(sid, "volumes")[-1][1]
    status = peer.session_rpc(sid, "status")
    assert [(c.name, c.ml) for c in vols.containers] == [(c.name, c.ml) for c in status.volumes]
    assert status.frames_done == 6 and status.sim_time_s == pytest.approx(metrics[-1].sim_time_s)

    reset = peer.session_rpc(sid, "reset")
    assert reset.sim_time_s == 0 and reset.frames_done == 6           # counters kept
    stamp = T0 + 100 * DT_NS
    peer.send(sid, "poses", poses_msg({"cup": UP}), stamp)
    m = peer.wait_output(sid, "metrics", stamp)
    assert m.sim_time_s == 0 and m.frames_done == 7                   # a reset session starts at 0
    peer.session_rpc(sid, "close")


@pytest.mark.parametrize("controller", ["pid", "mpc"])
def test_set_task_publishes_control(srv, controller):
    _, peer = srv
    sid = f"rpc-task-{controller}"
    peer.create(sid, pour_spec())
    peer.watch(sid)
    task = pb.Task(controller=controller)
    task.pour.source, task.pour.target, task.pour.volume_ml = "src", "dst", 5.0
    task.pour.max_angle_rad, task.pour.max_rate_rad_s = 2.0, 1.0
    st = peer.session_rpc(sid, "set_task", pb.SetTaskRequest(header=header(sid), task=task))
    assert st.task == task
    for i in range(3):
        peer.send(sid, "poses", poses_msg({"src": UP}), T0 + i * DT_NS)
        ctl = peer.wait_output(sid, "control", T0 + i * DT_NS)
        assert ctl.object == "src" and ctl.header.stamp_ns == T0 + i * DT_NS and ctl.controller == controller
        assert 0 <= ctl.remaining_ml <= 5.0 and not ctl.done and 0 <= ctl.tilt_angle_rad <= 2.0
        assert len(ctl.axis_point_m) == 3 and ctl.axis_direction[1] == 0.0
        assert abs(sum(a * a for a in ctl.axis_direction) - 1.0) < 1e-9
    cancel = peer.session_rpc(sid, "set_task", pb.SetTaskRequest(header=header(sid), task=pb.Task()))
    assert not cancel.HasField("task")
    peer.send(sid, "poses", poses_msg({"src": UP}), T0 + 10 * DT_NS)
    peer.wait_output(sid, "metrics", T0 + 10 * DT_NS)
    assert len(peer.of(sid, "control")) == 3
    # a pour that names no container of the scene
    task.pour.target = "nowhere"
    err = peer.error(f"{sid}/rpc/set_task", pb.SetTaskRequest(header=header(sid), task=task).SerializeToString())
    assert err.code == E.UNKNOWN_NAME and "nowhere" in err.message
    task.pour.target, task.pour.volume_ml = "dst", float("nan")
    err = peer.error(f"{sid}/rpc/set_task", pb.SetTaskRequest(header=header(sid), task=task).SerializeToString())
    assert err.code == E.NON_FINITE
    peer.session_rpc(sid, "close")


def _create(sid="rpc-err", spec=None, version=pb.PROTOCOL_VERSION_CURRENT, **kw) -> bytes:
    return pb.CreateSessionRequest(header=header(version=version), session_id=sid, spec=spec or cup_spec(),
                                   **kw).SerializeToString()


def _nan_pose():
    spec = cup_spec()
    spec.scene.objects[0].initial_pose[0] = float("nan")
    return spec


def _unknown_fill():
    spec = cup_spec()
    spec.scene.fills[0].container = "vase"
    return spec


ERRORS = {
    "garbage": ("rpc/create_session", b"\xff\xff\xff\xff", E.BAD_REQUEST),
    "no header": ("rpc/list_sessions", b"", E.UNSUPPORTED_VERSION),
    "version 2": ("rpc/create_session", _create(version=2), E.UNSUPPORTED_VERSION),
    "bad id": ("rpc/create_session", _create(sid="a/b"), E.BAD_REQUEST),
    "reserved id": ("rpc/create_session", _create(sid="rpc"), E.BAD_REQUEST),
    "unknown method": ("rpc/teleport", pb.ListSessionsRequest(header=header()).SerializeToString(), E.BAD_REQUEST),
    "unknown session method": ("nobody/rpc/teleport", pb.SessionRequest(header=header()).SerializeToString(),
                               E.BAD_REQUEST),
    "unknown session": ("nobody/rpc/status", pb.SessionRequest(header=header()).SerializeToString(),
                        E.UNKNOWN_SESSION),
    "header names another session": ("nobody/rpc/reset", pb.SessionRequest(header=header("other")).SerializeToString(),
                                     E.BAD_REQUEST),
    "too large": ("rpc/create_session", b"\x00" * 300_000, E.TOO_LARGE),
    "nan pose": ("rpc/create_session", _create(spec=_nan_pose()), E.NON_FINITE),
    "unknown fill container": ("rpc/create_session", _create(spec=_unknown_fill()), E.BAD_REQUEST),
    "unknown tracking mode": ("rpc/create_session", _create(spec=cup_spec(tracking=99)), E.BAD_REQUEST),
    "cuda": ("rpc/create_session", _create(spec=pb.SessionSpec(scene=cup_spec().scene, device="cuda")),
             E.INFEASIBLE),
    "no fill": ("rpc/create_session", _create(spec=pb.SessionSpec(scene=pb.SceneSpec(objects=cup_spec().scene.objects))),
                E.BAD_REQUEST),
}


@pytest.mark.parametrize("case", sorted(ERRORS))
def test_error_replies(srv, case):
    _, peer = srv
    key, payload, code = ERRORS[case]
    if case == "cuda":
        import torch
        if torch.cuda.is_available():
            pytest.skip("this machine has CUDA")
    err = peer.error(key, payload)
    assert err.code == code, (case, err)
    assert err.message


def test_already_exists_and_resource_exhausted(srv):
    _, peer = srv
    open_now = len(peer.list_sessions().sessions)
    made = [f"rpc-full-{i}" for i in range(3 - open_now)]
    for sid in made:
        peer.create(sid, cup_spec())
    assert peer.error("rpc/create_session", _create(sid=made[0])).code == E.ALREADY_EXISTS
    err = peer.error("rpc/create_session", _create(sid="rpc-one-too-many"))
    assert err.code == E.RESOURCE_EXHAUSTED and "--max-sessions" in err.message
    for sid in made:
        peer.session_rpc(sid, "close")
    assert peer.create("rpc-full-0", cup_spec()).state == "running"     # a closed id may be reused
    peer.session_rpc("rpc-full-0", "close")


def test_rejected_and_out_of_order_inputs_are_counted(srv):
    _, peer = srv
    sid = "rpc-rejects"
    peer.create(sid, cup_spec())
    peer.watch(sid)
    peer.send(sid, "camera", camera_msg(), T0)
    bad = [("poses", poses_msg({"cup": [0, 0, 0, 0, 0, 0, 1.1]})),          # not a unit quaternion
           ("poses", poses_msg({"cup": [float("nan"), 0, 0, 0, 0, 0, 1]})),
           ("poses", poses_msg({"teapot": UP})),
           ("mask", mask_msg(np.zeros((H + 1, W), bool))),
           ("mask", mask_msg(np.zeros((H, W), bool), encoding="rgb8")),
           ("mask", mask_msg(np.zeros((H, W), bool), camera="cam9")),
           ("image", pb.Header())]                                          # not an image at all
    for i, (stream, msg) in enumerate(bad):
        peer.send(sid, stream, msg, T0 + (i + 1) * DT_NS)
    peer.put(sid, "poses", poses_msg({"cup": UP}).SerializeToString(), None)             # no attachment
    peer.put(sid, "poses", poses_msg({"cup": UP}).SerializeToString(),
             header(sid, 0, T0, version=7).SerializeToString())                            # wrong version
    stamp = T0 + 20 * DT_NS
    peer.send(sid, "poses", poses_msg({"cup": UP}), stamp)
    peer.wait_output(sid, "metrics", stamp)
    peer.send(sid, "poses", poses_msg({"cup": UP}), stamp - 1)                            # older: out of order
    peer.send(sid, "poses", poses_msg({"cup": UP}), stamp + DT_NS)
    m = peer.wait_output(sid, "metrics", stamp + DT_NS)
    assert (m.rejected, m.dropped_out_of_order, m.frames_in, m.frames_done) == (len(bad) + 2, 1, 2, 2)
    peer.session_rpc(sid, "close")


def test_connect_mode_joins_a_router_with_its_own_prefix(servers, port):
    """``--connect`` (docker-compose's router) with ``--prefix``: the server listens on nothing
    and answers through the router it joined, under its prefix only."""
    import zenoh
    from zraw import Peer, ServeProc, wait_until

    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"router"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{port}"]')
    hub = zenoh.open(cfg)
    try:
        proc = ServeProc(servers.tmp / "state", "--prefix", "lab/twin", "--server-id", "srv-7", *[],
                         connect=f"tcp/127.0.0.1:{port}")
        servers.procs.append(proc)
        assert "ready on connected to tcp/127.0.0.1:" in proc.ready_line and "prefix lab/twin" in proc.ready_line
        peer = Peer(f"tcp/127.0.0.1:{port}", prefix="lab/twin")
        servers.peers.append(peer)
        # the router needs a moment to propagate the server's queryables
        wait_until(lambda: peer.query("rpc/list_sessions", b"", timeout=1)[0] == "err", 10)
        assert peer.list_sessions().server_id == "srv-7"
        alive = [str(r.ok.key_expr) for r in hub.liveliness().get("lab/twin/alive/servers/*", timeout=5) if r.ok]
        assert alive == ["lab/twin/alive/servers/srv-7"]
        other = Peer(f"tcp/127.0.0.1:{port}")                # default prefix: nobody answers
        servers.peers.append(other)
        assert other.query("rpc/list_sessions", b"", timeout=1)[0] == "none"
    finally:
        hub.close()
