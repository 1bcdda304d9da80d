"""End-to-end wall time of discrepancy discovery on one recording, per stage.

    OMP_NUM_THREADS=1 .venv/bin/python bench/discrepancy_speed.py [--scene pour_partial] [--quick] [--effect drag] [--jobs 2]
        [--ensemble K] [--score energy|distance] [--null-bar spread|magnitude]

Generates the recording (not timed; seed 4, cup 90 % full), runs ``discrepancy.analyse`` with
the default options (all ten candidates, calibration, 2 null runs, gains from 4 draws scored
by the energy score, the spread null bar; ``--ensemble``, ``--score``, ``--null-bar`` as
``liquidtwin discrepancy`` takes them) in ``--jobs`` processes
(``Options.jobs``; 1: all in this one) and prints the report's ``timing_s`` per stage, the
number of model evaluations, the decision with its fitted value beside the planted effect
(read from the truth sidecar after the analysis), the particle count, the recording's length,
and the peak resident memory of this process and, with ``--jobs`` > 1, of the largest worker
(each holds its own simulators). The issue's target: a 10-second single-camera recording in
under 10 minutes on 2 cores (the full ``pour_partial`` lasts 8.5 s). Appends one record to
bench/history.jsonl; ``--out`` keeps the report.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

HISTORY = Path(__file__).parent / "history.jsonl"


def _vm_hwm() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return 0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="pour_partial")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--effect", default="drag", help="planted effect (NAME or NAME=VALUE; 'none' for none)")
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--jobs", type=int, default=1, help="processes running the model evaluations (default 1)")
    p.add_argument("--out", type=Path, help="keep the report (report.json, report.md, plots) in this folder")
    p.add_argument("--ensemble", type=int, default=None, metavar="K",
                   help="Options.ensemble: the best candidates' gains from K draws "
                        "(default: Options's; 0: one rollout)")
    p.add_argument("--score", choices=("distance", "energy"), default=None,
                   help="Options.score: how the ensemble's draws are scored (default: Options's)")
    p.add_argument("--null-bar", choices=("magnitude", "spread"), default=None,
                   help="Options.null_bar: how the null gains set the bar (default: Options's)")
    args = p.parse_args()
    from liquidtwin.discrepancy import Options, analyse
    opt = Options(jobs=args.jobs, **{k: v for k, v in (("ensemble", args.ensemble), ("score", args.score),
                                                       ("null_bar", args.null_bar)) if v is not None})
    from liquidtwin.generate import generate
    from liquidtwin.generate.effects import parse_effect
    with tempfile.TemporaryDirectory() as d:
        rec = Path(d) / "rec.mcap"
        effects = [] if args.effect == "none" else [parse_effect(args.effect)]
        g = generate(args.scene, rec, effects=effects, seed=args.seed, quick=args.quick,
                     choices={"source": "cup", "fraction": 0.9})
        t0 = time.perf_counter()
        report = analyse([rec], args.out or Path(d) / "out", options=opt, progress=True)
        wall = time.perf_counter() - t0
        truth = json.loads(g.truth.read_text())      # read for scoring, after the analysis
    dur = report["_series"]["t"][0]
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    record = {"what": "discrepancy_end_to_end", "scene": args.scene, "quick": args.quick, "effect": args.effect,
              "particles": g.particles, "steps": g.steps, "mask_frames": g.masks, "wall_s": round(wall, 1),
              "timing_s": report["timing_s"], "evaluations": report["evaluations"], "decision": report["decision"],
              "fitted": next((c["value"] for c in report["candidates"] if c["name"] == report["decision"]), None),
              "planted": truth["effect"],
              "null_fitted": [c["name"] for c in report["candidates"] if "null_gains" in c],
              "residual_real": report["null"]["residual_real"],
              "ranked": [{"name": c["name"], "value": c["value"], "gain": round(c["heldout_gain"]["mean"], 4),
                          "ci95": [round(x, 4) for x in c["heldout_gain"]["ci95"]]} for c in report["candidates"][:3]],
              "informative_frames_s": [round(dur[0], 3), round(dur[-1], 3)] if dur else None,
              "jobs": args.jobs, "ensemble": opt.ensemble, "score": opt.score, "null_bar": opt.null_bar,
              "peak_mem_bytes": _vm_hwm(),
              "peak_worker_mem_bytes": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024 if args.jobs > 1 else None,
              "commit": commit,
              "date": datetime.now(timezone.utc).isoformat()}
    print(json.dumps(record, indent=1))
    with HISTORY.open("a") as f:
        f.write(json.dumps(record) + "\n")


if __name__ == "__main__":
    main()
