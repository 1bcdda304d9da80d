"""Why the drag fit came out high: its fitting loss against the drag coefficient, averaged over
realisations, for one setting of the model's solver iterations, the pose smoothing and the
sensors.

    OMP_NUM_THREADS=1 .venv/bin/python bench/discrepancy_drag_bias.py [--extra-iterations 2] \
        [--smoothing 0.05] [--sensors noisy|clean|no-pose-noise|no-pose-drift] [--seed 4] [--full]
    .venv/bin/python bench/discrepancy_drag_bias.py --table       # every record so far, as a table
    .venv/bin/python bench/discrepancy_drag_bias.py --pose-error  # the recording's pose velocity error only

The recording: ``pour_partial`` (cup 90 %, quick unless ``--full``) with a drag planted (its
value drawn from the seed). The model runs with the *world's* fluid parameters (read from the
truth sidecar: a diagnostic, not the blind analysis), so the calibration plays no part; each
coefficient is rolled out ``--realisations`` times (the first from the settled fill, the
others with 1 mm/s of initial-velocity jitter) and its mean fitting loss is what the analysis
would minimise. ``--sensors clean`` writes the recording without pose and mask noise;
``no-pose-noise`` without pose noise only (the generator's pose noise replaced by none here),
``no-pose-drift`` with the white pose jitter but without its slow drift.
Appends one record to bench/results/discrepancy_drag_bias.jsonl.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results" / "discrepancy_drag_bias.jsonl"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--extra-iterations", type=int, default=2, help="solver iterations added to the stated count")
    p.add_argument("--smoothing", type=float, default=0.05, help="σ of the pose smoothing, s (0: raw poses)")
    p.add_argument("--sensors", choices=("noisy", "clean", "no-pose-noise", "no-pose-drift"), default="noisy")
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--full", action="store_true", help="the full-size scene (default: quick)")
    p.add_argument("--values", default="0,2,3,4,5,6,8", help="drag coefficients, 1/m")
    p.add_argument("--realisations", type=int, default=4)
    p.add_argument("--table", action="store_true", help="print the records so far and exit")
    p.add_argument("--pose-error", action="store_true",
                   help="print the velocity error of the raw and the smoothed poses against the true ones and exit")
    args = p.parse_args()
    if args.table:
        return _table()
    import torch
    torch.set_num_threads(1)
    import liquidtwin.generate.generator as gen
    from liquidtwin.discrepancy.analysis import Options, prepare
    from liquidtwin.discrepancy.model import Extension
    from liquidtwin.discrepancy.residuals import cell_metrics, coarse
    from liquidtwin.sensors.poses import PoseNoise
    if args.sensors in ("no-pose-noise", "no-pose-drift"):
        noisy = gen.noisy_poses
        keep = PoseNoise.NONE if args.sensors == "no-pose-noise" else PoseNoise(drift_m=0.0, drift_rad=0.0)
        gen.noisy_poses = lambda poses, rng, noise=None: noisy(poses, rng, keep)
    values = [float(v) for v in args.values.split(",")]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        rec = Path(d) / "rec.mcap"
        g = gen.generate("pour_partial", rec, effects=[("drag", None)], seed=args.seed, quick=not args.full,
                         noise=args.sensors != "clean", choices={"source": "cup", "fraction": 0.9})
        truth = json.loads(g.truth.read_text())
        if args.pose_error:
            return _pose_error(rec, g.truth.with_suffix(".npz"), args.smoothing)
        opt = Options(extra_iterations=args.extra_iterations, pose_smoothing_s=args.smoothing)
        _, sims, _, frames, data, _, _ = prepare([rec], opt)
        sim, f, obs, fit = sims[0], frames[0], data.cells[0], data.fit[0]
        world = {k: float(truth["world"]["params"][k]) for k in ("lambda_v", "lambda_c")}
        jitter = torch.Generator().manual_seed(1)
        rows = []
        for c in values:
            ext = Extension("drag", {"c": c}, world) if c else Extension("none", {}, world)
            losses = []
            for r in range(args.realisations):
                x0, v0 = sim.initial(1.0)
                init = None if r == 0 else (x0, v0 + 1e-3 * torch.randn(v0.shape, generator=jitter))
                cells = coarse(sim.render(sim.rollout(ext, initial=init), f, ext=ext))
                losses.append(float(cell_metrics(cells, obs)["loss"][fit].mean()))
            rows.append({"c": c, "mean": float(np.mean(losses)), "std": float(np.std(losses, ddof=1)), "losses": losses})
            print(f"c = {c:4.1f} 1/m: fitting loss {np.mean(losses):.4f} ± {np.std(losses, ddof=1):.4f}", flush=True)
    best = min(rows, key=lambda r: r["mean"])
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    record = {"seed": args.seed, "quick": not args.full, "planted": truth["effect"]["value"],
              "world_iterations": truth["world"]["iterations"], "model_iterations": int(sim.model.iterations),
              "smoothing_s": args.smoothing, "sensors": args.sensors, "realisations": args.realisations,
              "rows": rows, "argmin": best["c"], "commit": commit, "wall_s": round(time.perf_counter() - t0, 1)}
    print(f"lowest mean loss at c = {best['c']} (planted {record['planted']:.2f}); model {record['model_iterations']} "
          f"iterations, world {record['world_iterations']}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    with RESULTS.open("a") as fh:
        fh.write(json.dumps(record) + "\n")


def _pose_error(rec: Path, truth_npz: Path, smoothing: float) -> None:
    """RMS error of the moving object's linear velocity and angular speed (finite differences
    between pose samples) in the recording, raw and smoothed, against the true poses."""
    from liquidtwin.discrepancy.episode import load_episode
    true = np.load(truth_npz)["true_poses"]
    for label, s in (("raw", 0.0), (f"smoothed, sigma {smoothing:g} s", smoothing)):
        ep = load_episode(rec, smoothing_s=s)
        k = int(np.argmax(np.abs(np.diff(true[..., :3], axis=0)).sum((0, 2))))    # the object that moves most
        dt = np.diff(ep.pose_t)[:, None]
        v = lambda P: np.diff(P[:, k, :3], axis=0) / dt                            # noqa: E731
        w = lambda P: 2 * np.arccos(np.clip(np.abs((P[1:, k, 3:] * P[:-1, k, 3:]).sum(-1)), 0, 1)) / dt[:, 0]  # noqa: E731
        print(f"{label:24s} velocity error {np.sqrt(((v(ep.poses) - v(true)) ** 2).mean()):.3f} m/s, "
              f"angular speed error {np.sqrt(((w(ep.poses) - w(true)) ** 2).mean()):.2f} rad/s")


def _table() -> None:
    """One row per record: mean fitting loss per coefficient, the lowest, and the analysis's
    own estimator on those means (``candidates._vertex``: a parabola in log c through the
    lowest and up to two points each side)."""
    from liquidtwin.discrepancy.candidates import _vertex
    recs = [json.loads(line) for line in RESULTS.read_text().splitlines() if line.strip()]
    cs = sorted({r["c"] for rec in recs for r in rec["rows"]})
    print("| seed | sensors | pose smoothing, s | model / world iterations | " + " | ".join(f"c={c:g}" for c in cs)
          + " | lowest at | parabola | planted |")
    print("|---" * (len(cs) + 7) + "|")
    for rec in recs:
        by = {r["c"]: r["mean"] for r in rec["rows"]}
        v = _vertex([(c, m) for c, m in by.items() if c > 0], log=True)
        print(f"| {rec['seed']} | {rec['sensors']} | {rec['smoothing_s']:g} | {rec['model_iterations']} / "
              f"{rec['world_iterations']} | " + " | ".join(f"{by[c]:.3f}" if c in by else "" for c in cs)
              + f" | {rec['argmin']:g} | {'—' if v is None else f'{v:.2f}'} | {rec['planted']:.2f} |")


if __name__ == "__main__":
    main()
