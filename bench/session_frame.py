"""Cost of one session frame and the trackers' IOU, without the service around it.

    .venv/bin/python bench/session_frame.py [--recording REC.mcap] [--frames 420]
                                            [--tracking open_loop warp_field map_filter]
                                            [--threads 1]

Feeds a recording's frames to a :class:`liquidtwin.session.SessionEngine` as the server does
(advance to the frame's stamp, correct with the mask stamped with it, read volumes) and
prints per tracker: particles, ms per frame for advance / correct / volumes, and the mean IOU
over frames whose mask shows ≥ 50 liquid px (before each correction, SPEC §2). Also times the
native neighbour search on the last state. Default recording: the bundled demo pour
(2.1k particles, 640×480). Records (``what`` = "session_frame") go to bench/history.jsonl.
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import time
from pathlib import Path

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from liquidtwin.demo import DEMO_RECORDING
from liquidtwin.recordings import read_recording
from liquidtwin.session import SessionEngine

ROOT = Path(__file__).resolve().parents[1]
MODES = {"open_loop": pb.OPEN_LOOP, "warp_field": pb.WARP_FIELD, "map_filter": pb.MAP_FILTER}


def run(rec, mode: str, frames: int) -> dict:
    camera = next(iter(rec.cameras))
    eng = SessionEngine.create(pb.SessionSpec(scene=rec.spec, tracking=MODES[mode]))
    cam = rec.cameras[camera]
    eng.set_camera(camera, K=cam.K, D=cam.D, width=cam.width, height=cam.height, pose=cam.pose)
    stamps, masks = rec.masks[camera]
    ms = {"advance": 0.0, "correct": 0.0, "volumes": 0.0}
    ious, corrections = [], 0
    n = min(frames, len(rec.pose_times_ns))
    for i in range(n):
        t = rec.pose_times_ns[i]
        t0 = time.perf_counter()
        eng.advance((t - rec.pose_times_ns[0]) * 1e-9, dict(zip(rec.object_names, rec.poses[i])))
        t1 = time.perf_counter()
        j = int(np.searchsorted(stamps, t))
        if j < len(stamps) and stamps[j] == t:
            c = eng.correct(camera, masks[j])
            corrections += 1
            if c.observed_px >= 50:
                ious.append(c.iou)
        t2 = time.perf_counter()
        eng.volumes()
        t3 = time.perf_counter()
        ms["advance"] += t1 - t0
        ms["correct"] += t2 - t1
        ms["volumes"] += t3 - t2
    from liquidtwin.sim import fused
    x = eng._state.x
    t0 = time.perf_counter()
    for _ in range(20):
        fused.sorted_neighbors(x, eng._scene.model.h + eng._scene.model.skin)
    return {"what": "session_frame", "tracking": mode, "particles": eng.n_particles, "frames": n,
            "advance_ms": round(1e3 * ms["advance"] / n, 1),
            "correct_ms": round(1e3 * ms["correct"] / max(corrections, 1), 1),
            "volumes_ms": round(1e3 * ms["volumes"] / n, 2),
            "frame_ms": round(1e3 * sum(ms.values()) / n, 1),
            "neighbors_ms": round(1e3 * (time.perf_counter() - t0) / 20, 2),
            "mean_iou": round(float(np.mean(ious)), 3) if ious else None, "iou_frames": len(ious)}


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--recording", type=Path, default=DEMO_RECORDING)
    p.add_argument("--frames", type=int, default=420, help="pose frames fed (default: %(default)s)")
    p.add_argument("--tracking", nargs="+", choices=sorted(MODES), default=["open_loop", "warp_field"])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--history", type=Path, default=ROOT / "bench" / "history.jsonl")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    rec = read_recording(a.recording, images=False)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=ROOT).stdout.strip() or "unknown"
    date = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    records = []
    for mode in a.tracking:
        r = run(rec, mode, a.frames)
        r.update(recording=a.recording.name, threads=a.threads, commit=commit, date=date,
                 peak_mem_bytes=_peak())
        records.append(r)
        print(json.dumps(r), flush=True)
    if a.history.parent.is_dir():
        with a.history.open("a") as f:
            f.writelines(json.dumps(r) + "\n" for r in records)
    return records


def _peak() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return 0


if __name__ == "__main__":
    main()
