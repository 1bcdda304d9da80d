"""Sessions side by side: two sessions of different scenes streamed at once give exactly
the results each gives alone, and nothing crosses between them; a session whose client's
liveliness token vanishes is orphaned, then closed after the grace time."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest
from liquidtwin_proto import liquidtwin_pb2 as pb
from zraw import CAM_POSE, H, W, camera_msg, cloud_arrays, cup_spec, mask_msg, poses_msg, pour_spec, wait_until

T0 = 1_700_000_000_000_000_000
DT_NS = 33_333_333
FRAMES = 25


@pytest.fixture(scope="module")
def srv(module_servers):
    proc = module_servers.start("--orphan-grace-s", "1")
    yield proc, module_servers.peer(proc)
    assert proc.alive(), proc.stderr()[-3000:]


def _tilt(i: int) -> list:
    a = 0.3 * np.sin(i / 6)                      # rock about z: the liquid moves
    return [0, 0, 0, 0, 0, float(np.sin(a / 2)), float(np.cos(a / 2))]


SCENES = {
    # cup, closed loop on a mask every other frame
    "a": (cup_spec(fraction=0.15, tracking=pb.WARP_FIELD), "cup"),
    # cup beside a bowl, open loop, the cup rocking
    "b": (pour_spec(), "src"),
}


def _stream(peer, sid: str, key: str, errors: list) -> None:
    try:
        spec, obj = SCENES[key]
        mask = np.zeros((H, W), bool)
        mask[40:80, 60:100] = True
        if key == "a":
            peer.send(sid, "camera", camera_msg(), T0 - 1)
        for i in range(FRAMES):
            stamp = T0 + i * DT_NS
            if key == "a" and i % 2 == 0:
                peer.send(sid, "mask", mask_msg(mask), stamp)
            poses = {obj: _tilt(i)}
            if key == "a":
                poses["cam0"] = CAM_POSE
            peer.send(sid, "poses", poses_msg(poses), stamp)
            peer.wait_output(sid, "metrics", stamp, timeout=30)
    except Exception as exc:  # noqa: BLE001 - reported by the test thread
        errors.append((sid, exc))


def _results(peer, sid):
    clouds = {h.stamp_ns: cloud_arrays(m) for h, m in peer.of(sid, "particles")}
    vols = {h.stamp_ns: [(c.name, c.ml) for c in m.containers] for h, m in peer.of(sid, "volumes")}
    ious = [m.iou for _, m in peer.of(sid, "metrics")]
    return clouds, vols, ious


def test_two_sessions_at_once_equal_each_alone(srv):
    _, peer = srv
    runs = {}
    for phase, keys in (("alone", [["a"], ["b"]]), ("together", [["a", "b"]])):
        for group in keys:
            errors, threads = [], []
            for key in group:
                sid = f"{key}-{phase}"
                st = peer.create(sid, SCENES[key][0])
                runs[sid] = st
                peer.watch(sid)
                threads.append(threading.Thread(target=_stream, args=(peer, sid, key, errors)))
            for t in threads:
                t.start()
            for t in threads:
                t.join(120)
            assert not errors, errors
    for key in SCENES:
        alone, together = _results(peer, f"{key}-alone"), _results(peer, f"{key}-together")
        assert len(alone[0]) == len(together[0]) == FRAMES
        for stamp, (pos, speed) in alone[0].items():
            pos_t, speed_t = together[0][stamp]
            np.testing.assert_array_equal(pos, pos_t)          # bit for bit
            np.testing.assert_array_equal(speed, speed_t)
        assert alone[1] == together[1]
        np.testing.assert_array_equal(alone[2], together[2])
        moved = np.abs(alone[0][T0 + (FRAMES - 1) * DT_NS][0].mean(0) - alone[0][T0][0].mean(0)).max()
        assert moved > 1e-3                                    # the runs did something
    # nothing crossed: each session's outputs carry its id, its own particle count and containers
    assert runs["a-alone"].particles != runs["b-alone"].particles
    for sid, st in runs.items():
        count = {h.stamp_ns: m.particles for h, m in peer.of(sid, "metrics")}
        assert 0 < min(count.values()) <= max(count.values()) <= st.particles   # liquid spilled over the rim may
        for stream, h, m in peer.outputs[sid]:                                  # fall away and be culled
            assert h.session_id == sid
            if stream == "particles":
                assert len(m.data) == 16 * count[h.stamp_ns]
            if stream == "volumes":
                assert [c.name for c in m.containers] == [v.name for v in st.volumes]
    assert len(peer.of("a-together", "overlay")) == (FRAMES + 1) // 2 and not peer.of("b-together", "overlay")
    for sid in runs:
        peer.session_rpc(sid, "close")


def _state(peer, sid):
    return {s.session_id: s.state for s in peer.list_sessions().sessions}.get(sid, "gone")


def test_vanished_client_orphans_then_closes(srv):
    proc, peer = srv
    peer.token("c-gone")
    peer.token("c-stays")
    peer.create("orphan", cup_spec(), client_id="c-gone")
    peer.create("kept", cup_spec(), client_id="c-stays")
    peer.create("anon", cup_spec())
    peer.drop_token("c-gone")
    wait_until(lambda: _state(peer, "orphan") == "orphaned", 5)
    wait_until(lambda: _state(peer, "orphan") == "gone", 5)
    meta = json.loads((proc.state_dir / "sessions" / "orphan" / "meta.json").read_text())
    assert meta["state"] == "closed"
    assert _state(peer, "kept") in ("running", "idle") and _state(peer, "anon") in ("running", "idle")
    # an RPC adopts an orphaned session again (for another grace period)
    peer.token("c-brief")
    peer.create("adopted", cup_spec(), client_id="c-brief")
    peer.drop_token("c-brief")
    wait_until(lambda: _state(peer, "adopted") == "orphaned", 5)
    assert peer.session_rpc("adopted", "status").state == "running"
    for sid in ("kept", "anon"):
        peer.session_rpc(sid, "close")
    assert "session orphan orphaned" in proc.stderr()
