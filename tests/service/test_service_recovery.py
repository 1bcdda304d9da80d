"""kill -9 in the middle of a stream, restart with the same state dir: the session comes
back restored from its checkpoint and carries on, and its MCAP logs (the killed, footerless
segment and the new one) hold every input the client saw answered and all sent after."""

from __future__ import annotations

import time

import numpy as np
import torch
from liquidtwin.service import read_log, read_segment, segments
from liquidtwin_proto import liquidtwin_pb2 as pb
from zraw import CAM_POSE, H, W, camera_msg, cloud_arrays, cup_spec, mask_msg, poses_msg

UP = [0, 0, 0, 0, 0, 0, 1]
T0 = 1_700_000_000_000_000_000
DT_NS = 33_333_333
MCAP_MAGIC = b"\x89MCAP0\r\n"


def _frame(peer, sid, i, sent, mask):
    stamp = T0 + i * DT_NS
    if i % 3 == 0:
        peer.send(sid, "mask", mask_msg(mask), stamp)
        sent["mask"].append(stamp)
    peer.send(sid, "poses", poses_msg({"cup": UP, "cam0": CAM_POSE}), stamp)
    sent["poses"].append(stamp)
    return stamp


def test_kill9_restart_restores_the_session_and_loses_no_logged_input(servers):
    sid = "recover"
    first = servers.start("--checkpoint-s", "0.2")
    peer = servers.peer(first)
    peer.token("robot")
    peer.create(sid, cup_spec(tracking=pb.WARP_FIELD), client_id="robot")
    peer.watch(sid)
    peer.send(sid, "camera", camera_msg(), T0 - 1)
    mask = np.zeros((H, W), bool)
    mask[45:75, 60:100] = True
    sent = {"poses": [], "mask": []}
    for i in range(20):                                   # lockstep: each frame answered
        peer.wait_output(sid, "particles", _frame(peer, sid, i, sent, mask))
    time.sleep(0.8)                                       # a checkpoint after frame 19 (every 0.2 s)
    for i in range(20, 30):                               # then frames in flight at the kill
        _frame(peer, sid, i, sent, mask)
        time.sleep(0.005)
    first.kill()
    answered = {h.stamp_ns for h, _ in peer.of(sid, "particles")}
    assert {T0 + i * DT_NS for i in range(20)} <= answered
    d = first.state_dir / "sessions" / sid
    ckpt = torch.load(d / "checkpoint.pt", weights_only=True)
    ckpt_t = ckpt["engine"]["sim_t"]
    assert ckpt_t >= 19 * DT_NS / 1e9 - 1 / 60 and ckpt["service"]["first_ns"] == T0
    assert not (d / "log-0000.mcap").read_bytes().endswith(MCAP_MAGIC)     # killed: no footer

    second = servers.start("--checkpoint-s", "0.2", state_dir=first.state_dir)
    print(f"restart to ready: {second.ready_s:.2f} s ({second.ready_line})")
    assert "1 session(s) restored" in second.ready_line
    peer2 = servers.peer(second)
    peer2.token("robot")
    (st,) = peer2.list_sessions().sessions
    assert (st.session_id, st.restored, st.state) == (sid, True, "running")
    assert st.sim_time_s == ckpt_t and st.frames_done == ckpt["service"]["counters"]["frames_done"]
    assert st.log_path.endswith("log-0001.mcap")
    peer2.watch(sid)
    peer2._seq.update(peer._seq)                      # the client keeps counting its sequence numbers
    sent_after = []
    for i in range(40, 50):
        stamp = _frame(peer2, sid, i, sent, mask)
        sent_after.append(stamp)
        m = peer2.wait_output(sid, "metrics", stamp)
        pos, _ = cloud_arrays(peer2.wait_output(sid, "particles", stamp))
        assert pos.shape == (m.particles, 3) and 0 < m.particles <= st.particles and np.isfinite(pos).all()
        # the simulation clock continues from the checkpoint and follows the frame stamps
        assert m.sim_time_s >= ckpt_t and abs(m.sim_time_s - (stamp - T0) / 1e9) <= 1 / 60 + 1e-9
    metrics = [m for _, m in peer2.of(sid, "metrics")]
    assert metrics[0].sim_lag_s > 0                      # the gap was jumped, not simulated for
    assert all(m.sim_lag_s == 0 for m in metrics[1:])
    assert metrics[-1].frames_done == st.frames_done + 10
    assert sum(m.iou == m.iou for m in metrics) >= 3     # masks used after the restart too

    # every input the client saw answered before the kill, and all sent after, are in the logs
    second.stop()
    assert [p.name for p in segments(d)] == ["log-0000.mcap", "log-0001.mcap"]
    logged = {}
    for r in read_log(d):
        if r.topic.startswith("/in/"):
            logged.setdefault(r.topic, set()).add(r.publish_time_ns)
    assert {T0 - 1} == logged["/in/camera"]
    seen_poses = answered | set(sent_after)
    assert seen_poses <= logged["/in/poses"] <= set(sent["poses"])
    masks_of_seen = {s for s in sent["mask"] if s in seen_poses}
    assert masks_of_seen <= logged["/in/mask"]
    out_stamps = {r.publish_time_ns for r in read_log(d) if r.topic == "/out/particles"}
    assert answered <= out_stamps                     # what was published was logged too
    print(f"killed segment: {sum(1 for _ in read_segment(d / 'log-0000.mcap'))} records read back; "
          f"{len(answered)} frames answered before the kill, {len(logged['/in/poses'])} poses logged")


def test_a_segment_cut_anywhere_reads_back_up_to_the_cut(tmp_path):
    from liquidtwin.service import SessionLog

    log = SessionLog(tmp_path / "s", cup_spec())
    msgs = [poses_msg({"cup": [i * 0.01, 0, 0, 0, 0, 0, 1]}) for i in range(20)]
    for i, m in enumerate(msgs):
        log.write("/in/poses", m, T0 + i, T0 + i, i)
    raw = log.path.read_bytes()                           # flushed per message, not closed yet
    full = [r.data for r in read_segment(log.path)]
    assert full[0] == cup_spec().SerializeToString() and full[1:] == [m.SerializeToString() for m in msgs]
    cut_path = tmp_path / "cut.mcap"
    counts = []
    # every 97 bytes, and the whole file (the step alone may stop inside the last message)
    for cut in [*range(len(raw) // 3, len(raw), 97), len(raw)]:
        cut_path.write_bytes(raw[:cut])
        got = [r.data for r in read_segment(cut_path)]
        assert got == full[:len(got)]                     # a prefix, never garbage
        counts.append(len(got))
    assert counts == sorted(counts) and counts[-1] >= len(full) - 1 and counts[0] < len(full)
    log.close()
    assert log.path.read_bytes().endswith(MCAP_MAGIC)
    assert [r.data for r in read_segment(log.path)] == full


def test_sigterm_shuts_down_cleanly_and_a_restart_restores(servers):
    proc = servers.start("--checkpoint-s", "60")            # only the shutdown checkpoint
    peer = servers.peer(proc)
    peer.create("term", cup_spec())
    peer.watch("term")
    for i in range(4):
        peer.send("term", "poses", poses_msg({"cup": UP}), T0 + i * DT_NS)
        peer.wait_output("term", "metrics", T0 + i * DT_NS)
    sim_t = peer.session_rpc("term", "status").sim_time_s
    assert proc.stop() == 0
    d = proc.state_dir / "sessions" / "term"
    assert (d / "log-0000.mcap").read_bytes().endswith(MCAP_MAGIC)         # footer written
    assert torch.load(d / "checkpoint.pt", weights_only=True)["engine"]["sim_t"] == sim_t
    assert "shutting down" in proc.log.read_text()
    again = servers.start(state_dir=proc.state_dir)
    (st,) = servers.peer(again).list_sessions().sessions
    assert st.restored and st.sim_time_s == sim_t and st.frames_done == 4


def test_cli_refuses_cuda_without_cuda_and_bad_options(tmp_path):
    import subprocess

    from zraw import BIN
    if torch.cuda.is_available():
        return
    run = subprocess.run([str(BIN / "liquidtwin"), "serve", "--device", "cuda", "--state-dir", str(tmp_path)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "CUDA" in run.stderr
    run = subprocess.run([str(BIN / "liquidtwin"), "serve", "--prefix", "a//b", "--state-dir", str(tmp_path)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "prefix" in run.stderr
