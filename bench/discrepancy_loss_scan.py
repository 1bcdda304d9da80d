"""Where is a candidate's fitting loss lowest? A dense scan of one candidate's main parameter
on a generated recording, with the analysis's calibrated base and with the world's own fluid
parameters (read from the truth sidecar: a diagnostic of the blind analysis, not part of it).

    OMP_NUM_THREADS=1 .venv/bin/python bench/discrepancy_loss_scan.py [--quick] [--effect drag] \
        [--values 0,2,3,4,5,6,8] [--jobs 2] [--out bench/results/discrepancy_loss_scan.json]

It answers why a fitted value lands where it does: if the loss is lowest near the planted value
with the world's fluid parameters but not with the calibrated ones, the calibration's error is
absorbed by the candidate; if it is lowest away from the planted value either way, the model
differs from the world in something else (solver iterations, the settled fill); if it is lowest
near the planted value with the calibrated base too, the search misses the minimum. Writes the
JSON and a PNG of fitting and held-out loss against the parameter.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="pour_partial")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--effect", default="drag", help="planted effect (NAME or NAME=VALUE)")
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--values", default="0,2,3,4,5,6,8", help="the candidate's main parameter, comma-separated")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--out", default="bench/results/discrepancy_loss_scan.json")
    args = p.parse_args()
    from liquidtwin.discrepancy.analysis import Options, _held, calibrate, prepare
    from liquidtwin.discrepancy.candidates import LIBRARY
    from liquidtwin.discrepancy.model import Extension
    from liquidtwin.generate import generate
    from liquidtwin.generate.effects import parse_effect
    effect = parse_effect(args.effect)
    cand = LIBRARY[effect[0]]
    values = [float(v) for v in args.values.split(",")]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        rec = Path(d) / "rec.mcap"
        g = generate(args.scene, rec, effects=[effect], seed=args.seed, quick=args.quick,
                     choices={"source": "cup", "fraction": 0.9}, progress=True)
        eps, sims, ev, frames, data, split, pool = prepare([rec], Options(jobs=args.jobs))
        try:
            base, calib = calibrate(sims, ev, pool, data)
            truth = json.loads(g.truth.read_text())     # only after the calibration, for the oracle base
            world = {k: float(truth["world"]["params"][k]) for k in ("lambda_v", "lambda_c")}
            rows = []
            for label, b in (("calibrated", base.base), ("world", world)):
                exts = [Extension(effect[0], {cand.key: v}, b) if v != 0 else Extension("none", {}, b) for v in values]
                if pool is not None:
                    pool.draw(exts)
                for v, e in zip(values, exts):
                    fit = ev.fit_loss(e, data)
                    held, _ = _held(ev.losses(e, data.cells), data)
                    rows.append({"base": label, "lambda": b, "value": v, "fit_loss": fit,
                                 "heldout_loss": float(held.mean())})
                    print(f"{label:10s} {cand.key}={v:7.3f}  fit {fit:.5f}  held-out {held.mean():.5f}", flush=True)
        finally:
            if pool is not None:
                pool.close()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    result = {"scene": args.scene, "quick": args.quick, "seed": args.seed, "planted": truth["effect"],
              "world": {"params": world, "iterations": truth["world"]["iterations"]},
              "model_iterations": int(sims[0].model.iterations), "calibrated": base.base, "calibration": calib,
              "particles": g.particles, "steps": g.steps, "rows": rows, "commit": commit,
              "wall_s": round(time.perf_counter() - t0, 1)}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    _plot(result, cand.key, out.with_suffix(".png"))
    print(f"wrote {out} and {out.with_suffix('.png')}")


def _plot(result: dict, key: str, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, metric in zip(axes, ("fit_loss", "heldout_loss")):
        for label in ("calibrated", "world"):
            rows = [r for r in result["rows"] if r["base"] == label]
            ax.plot([r["value"] for r in rows], [r[metric] for r in rows], "o-", label=f"{label} base")
        ax.axvline(result["planted"]["value"], color="k", ls="--", label="planted")
        ax.set_xlabel(key)
        ax.set_title(metric.replace("_", " "))
        ax.legend()
    fig.suptitle(f"{result['scene']}{' (quick)' if result['quick'] else ''}: {result['planted']['name']} "
                 f"{result['planted']['value']:.3g}, seed {result['seed']}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    main()
