"""Simulation speed where it matters: a full-size pour rolled out open loop, as the discrepancy
analysis, fill inference and open-loop tracking run it.

    OMP_NUM_THREADS=1 .venv/bin/python bench/pour_rollout.py [--recording REC.mcap] [--steps N] [--backend torch] [--no-history]

Default recording: the full (not quick) ``pour_partial`` of a cup 90 % full, drag planted,
seed 4 — the scene of ``bench/discrepancy_speed.py`` at full size (generated into
``bench/results/`` when missing, a few minutes; 8.5 s, ~3.6k particles, 6 solver iterations).
Rolls the recording's stated model through its poses (``discrepancy.rollout.Simulator``, one
torch thread unless ``OMP_NUM_THREADS`` says otherwise) for ``--steps`` steps (default: all),
timing the steps and, separately, the neighbour-list builds (``sim.pbf._Lists``): how many
per step, and their share of the time. ``--profile`` runs it under cProfile and adds the time
spent inside the C++ kernels (``liquidtwin._native``) and outside them (Python and small
torch ops; cProfile slows the calls a little). ``--backend torch`` runs the pure-torch
reference path instead of the kernels: what an install whose extension did not build runs
(``server/native_build.py``). ``--cut-wall-pairs`` cuts the pairs a wall separates
(``sim.walls``). Prints one JSON record and appends it to bench/history.jsonl.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from pathlib import Path

import torch

from _record import emit

DEFAULT = Path(__file__).resolve().parent / "results" / "pour_rollout_cup90_s4.mcap"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--recording", type=Path, default=DEFAULT)
    p.add_argument("--steps", type=int, default=None, help="steps to roll (default: the whole recording)")
    p.add_argument("--no-history", action="store_true", help="print only; do not append to bench/history.jsonl")
    p.add_argument("--profile", action="store_true", help="split the time into the C++ kernels and the rest (cProfile)")
    p.add_argument("--cut-wall-pairs", action="store_true",
                   help="cut neighbour pairs that a wall separates (FluidModel.wall_pairs False, as the control "
                        "tasks; their cost lands in the list builds)")
    p.add_argument("--backend", choices=("auto", "torch"), default="auto",
                   help="auto: the C++ kernels where built; torch: the pure-torch reference path (default: auto)")
    args = p.parse_args()
    from liquidtwin.discrepancy.episode import load_episode
    from liquidtwin.discrepancy.model import Extension
    from liquidtwin.discrepancy.rollout import Simulator
    from liquidtwin.sim import pbf
    if not args.recording.exists():
        if args.recording != DEFAULT:
            raise SystemExit(f"no such recording: {args.recording}")
        from liquidtwin.generate import generate
        from liquidtwin.generate.effects import parse_effect
        print(f"generating {DEFAULT} (full pour_partial, cup 90 %, drag, seed 4) ...", flush=True)
        generate("pour_partial", DEFAULT, effects=[parse_effect("drag")], seed=4, quick=False,
                 choices={"source": "cup", "fraction": 0.9})
    sim = Simulator(load_episode(args.recording))
    sim.model = sim.model.replace(backend=args.backend, wall_pairs=not args.cut_wall_pairs)
    steps = sim.steps if args.steps is None else min(args.steps, sim.steps)

    builds, build_s = 0, 0.0
    original = pbf._Lists._build

    def timed(self, x):
        nonlocal builds, build_s
        t = time.perf_counter()
        out = original(self, x)
        build_s += time.perf_counter() - t
        builds += 1
        return out

    pbf._Lists._build = timed
    prof = cProfile.Profile() if args.profile else None
    try:
        t = time.perf_counter()
        if prof is not None:
            prof.enable()
        traj = sim.rollout(Extension(), steps=steps)
        if prof is not None:
            prof.disable()
        wall = time.perf_counter() - t
    finally:
        pbf._Lists._build = original
    split = {}
    if prof is not None:
        stats = pstats.Stats(prof).stats        # {(file, line, name): (cc, nc, tottime, cumtime, callers)}
        kernels = sum(v[2] for k, v in stats.items() if "liquidtwin._native" in k[2])
        split = {"kernels_s": round(kernels, 2), "outside_kernels_s": round(wall - kernels, 2)}
    n0 = int(traj.x[0].shape[0])
    particle_steps = sum(int(x.shape[0]) for x in traj.x[1:])
    emit({"what": "pour_rollout", "recording": args.recording.name, "particles": n0, "steps": steps,
          "iterations": int(sim.model.iterations), "backend": args.backend, "cut_wall_pairs": args.cut_wall_pairs, "threads": torch.get_num_threads(), "seconds": round(wall, 2),
          "particle_steps_per_s": round(particle_steps / wall), "neighbor_builds_per_step": round(builds / steps, 2),
          "neighbor_build_share": round(build_s / wall, 3), **split}, history=not args.no_history)


if __name__ == "__main__":
    main()
