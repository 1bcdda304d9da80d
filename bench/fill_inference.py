"""Wall time of a fill-hypothesis bank: batched (one simulation) vs sequential (one per hypothesis).

    .venv/bin/python bench/fill_inference.py [--recording REC.mcap] [--fractions 0.6 0.7 0.8 0.9]
                                             [--seconds 10] [--tracking open_loop] [--threads 2]

Builds the fill hypotheses of the recording's first filled container (each settled the way a
session fills its scene), then runs the bank over the first ``--seconds`` of the recording
twice — all hypotheses in one state (batched) and each alone, one after another — and prints
particles per hypothesis, simulation steps, scored frames, wall times and the speed-up, and
the largest difference of the two runs' log likelihoods. Default recording: a full (not
quick) generated ``pour_hold`` of a cup, 90 % full, seed 5 (generated into
``bench/results/`` when missing, ~1.5 min; a 90 % bottle does not fit the generator's lattice); default fractions 0.6–0.9 of the cup
give 2.5k–3.6k particles per hypothesis (the generator's fills stop within ~7 %). A record (``what`` = "fill_inference") is appended to
bench/history.jsonl.
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

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "bench" / "results" / "fill_bench_cup90_s5.mcap"


def _recording(path: Path):
    from liquidtwin.generate import generate
    from liquidtwin.recordings import read_recording
    if not path.exists():
        print(f"generating {path} (full pour_hold, cup 90 %, seed 5) ...", flush=True)
        generate("pour_hold", path, seed=5, quick=False, choices={"source": "cup", "fraction": 0.9})
    return read_recording(path, images=False)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--recording", type=Path, default=DEFAULT)
    p.add_argument("--fractions", type=float, nargs="+", default=[0.6, 0.7, 0.8, 0.9])
    p.add_argument("--seconds", type=float, default=10.0, help="analyse the first S s of the recording")
    p.add_argument("--tracking", default="open_loop", choices=["open_loop", "warp_field", "map_filter"])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--history", type=Path, default=ROOT / "bench" / "history.jsonl")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    from liquidtwin.inference import Bank, fill_hypotheses, run_bank
    rec = _recording(a.recording)
    t0 = rec.pose_times_ns[0]
    frames = int(np.searchsorted(rec.pose_times_ns, t0 + int(a.seconds * 1e9), side="right"))
    name = next(f.container for f in rec.spec.fills)
    start = time.perf_counter()
    scene, hyps = fill_hypotheses(rec.spec, name, tuple(a.fractions))
    build_s = time.perf_counter() - start
    bank = Bank(scene.model, hyps, scene.occluders, tracking=a.tracking)
    batched = run_bank(bank, rec, scene.model.dt, frames=frames, batched=True)
    sequential = run_bank(bank, rec, scene.model.dt, frames=frames, batched=False)
    steps = int(round((rec.pose_times_ns[frames - 1] - t0) * 1e-9 / scene.model.dt))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=ROOT).stdout.strip()
    r = {"what": "fill_inference", "recording": a.recording.name, "tracking": a.tracking,
         "hypotheses": len(hyps), "particles": bank.counts, "seconds": round((rec.pose_times_ns[frames - 1] - t0) * 1e-9, 3),
         "steps": steps, "frames_scored": batched.frames, "build_s": round(build_s, 1),
         "batched_s": round(batched.wall_s, 1), "sequential_s": round(sequential.wall_s, 1),
         "speedup": round(sequential.wall_s / batched.wall_s, 3),
         "max_ll_difference": float(np.abs(batched.log_likelihood - sequential.log_likelihood).max()),
         "threads": a.threads, "commit": commit,
         "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    for k, v in r.items():
        print(f"{k:>20}: {v}")
    if a.history.parent.is_dir():
        with a.history.open("a") as f:
            f.write(json.dumps(r) + "\n")
    return r


if __name__ == "__main__":
    main()
