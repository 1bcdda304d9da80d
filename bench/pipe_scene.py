"""Where does the pipe scene's liquid go? The routing of ``liquidtwin evaluate blockage``'s
recordings, read from their truth sidecars (the true particles).

    OMP_NUM_THREADS=1 python bench/pipe_scene.py [--quick] [--data DIR] [--seed N] [--partial F] [--jobs 2]

For each of the five pipe recordings (one per true blockage, the benchmark's seeds; generated
into ``--data`` when missing, as ``evaluate blockage`` does): the share of the liquid that
entered the junction's inlet (a particle inside the vertical stem at some sampled step), and
the shares that end in the left bowl, in the right bowl and elsewhere (a particle counts as
in a bowl inside the cylinder of its rim). A blockage is only observable through the bowls
and the legs' streams, so this is what the blockage inference has to go on.

Writes ``--out`` (JSON) and appends one record per recording to bench/history.jsonl.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from _record import emit

RESULTS = Path(__file__).resolve().parent / "results"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the quick pipe scenes (20 %% of the liquid, 320x240)")
    ap.add_argument("--data", type=Path, default=Path("eval-data"), help="recordings (generated when missing)")
    ap.add_argument("--seed", type=int, default=0, help="base seed, as evaluate blockage --seed")
    ap.add_argument("--jobs", type=int, default=2, help="processes generating missing recordings")
    ap.add_argument("--partial", type=float, default=None, metavar="F",
                    help="a partial plug blocks the lower F of its leg (default: evaluate blockage's)")
    ap.add_argument("--out", type=Path, default=None, help="JSON results (default bench/results/pipe_scene_*.json)")
    args = ap.parse_args()
    from liquidtwin.evaluate.blockage import ensure_pipes, pipe_cases, routing
    from liquidtwin.generate.catalog import build_setup
    from liquidtwin.inference import PARTIAL
    cases = pipe_cases(quick=args.quick, base_seed=args.seed, partial=PARTIAL if args.partial is None else args.partial)
    paths = ensure_pipes(cases, args.data, jobs=args.jobs)
    setup = build_setup("pipe", np.random.default_rng(0), args.quick)     # the seed only moves the camera
    rows = []
    for case, path in zip(cases, paths):
        particles = np.load(path.with_suffix(".truth.npz"))["particles"]
        row = {"bench": "pipe_scene", "recording": path.name, "truth": case.truth, "seed": case.seed,
               "quick": bool(args.quick), "partial_plug": case.partial, **routing(setup, particles)}
        rows.append(emit(row))
    print(f"{'truth':<15}{'entered inlet':>15}{'left bowl':>11}{'right bowl':>12}{'elsewhere':>11}")
    for r in rows:
        print(f"{r['truth']:<15}{r['entered_inlet']:>15.1%}{r['left_bowl']:>11.1%}{r['right_bowl']:>12.1%}"
              f"{r['elsewhere']:>11.1%}")
    out = args.out or RESULTS / f"pipe_scene_{'quick' if args.quick else 'full'}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
