"""What the discrepancy analysis's null misses: the calibrated base model's held-out loss
against the recording, and against realisations of the base model drawn several ways.

    OMP_NUM_THREADS=1 .venv/bin/python bench/discrepancy_null.py REC.mcap [REC2.mcap …] [--runs 3]
    .venv/bin/python bench/discrepancy_null.py REC.mcap … --noise-only    # the tracker noise levels

The analysis's null (``analysis._null_cells``) draws the world as the fitted base model. Until
stop 34 that was the model itself: the same smoothed poses, 1 mm/s of initial-velocity
jitter and mid-range mask noise. A recording differs from the model in more ways than that.
Each variant draws ``--runs`` realisations and reports their held-out loss against the base
model, so a variant that closes the gap to the recording's loss names what the null lacked:

- ``own_chaos``: the null before stop 34 (``_null_cells(vary=False)``);
- ``poses``:     plus the world moving along redrawn poses (``Episode.redrawn_poses``: fresh
                 tracker noise at the level estimated from the recording, smoothed as on
                 loading): the pose error the model itself carries;
- ``params``:    plus λ_v, λ_c drawn within ``NULL_PARAM_SPREAD`` of the calibrated ones;
- ``analysis``:  both — the analysis's null now (``_null_cells(vary=True)``).

With ``--truth`` (generated recordings only; reads the truth sidecar, so it is a diagnostic,
never part of an analysis) two more: ``true_noise`` (own_chaos with the recording's own mask
noise) and ``replica`` (the true world parameters, the true poses and the true mask noise:
the recording's process with other chaos).

Prints one table per recording and writes --out JSON when given.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("recordings", nargs="+", type=Path)
    p.add_argument("--runs", type=int, default=3, help="realisations per variant")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--truth", action="store_true", help="add the diagnostic variants that read the truth sidecar")
    p.add_argument("--out", type=Path, help="JSON file for the results")
    p.add_argument("--noise-only", action="store_true",
                   help="only print the tracker noise each recording's raw poses show (no rollouts)")
    args = p.parse_args()
    import torch
    torch.set_num_threads(1)
    from liquidtwin.discrepancy.analysis import (NULL_JITTER, NULL_NOISE, NULL_PARAM_SPREAD, NULL_POSE_DRIFT,
                                                 NULL_POSE_DRIFT_S, Options, _held, _null_cells, calibrate, prepare)
    from liquidtwin.discrepancy.model import Extension
    from liquidtwin.discrepancy.residuals import coarse
    from liquidtwin.recordings._interp import interpolate_poses
    from liquidtwin.sensors import MaskNoise
    from liquidtwin.sensors.masks import corrupt_mask

    if args.noise_only:
        from liquidtwin.discrepancy.episode import load_episode
        for rec in args.recordings:
            ep = load_episode(rec)
            print(rec.name, "  ".join(f"{n}: {pos * 1e3:.2f} mm {np.degrees(rot):.2f}°"
                                      for n, (pos, rot) in zip(ep.object_names, ep.pose_noise)))
        return
    results = []
    for rec in args.recordings:
        eps, sims, ev, frames, data, _, _ = prepare([rec], Options())
        ep, sim, f = eps[0], sims[0], frames[0]
        base, _ = calibrate(sims, ev, None, data)
        held_base = float(_held(ev.losses(base, data.cells), data)[0].mean())
        truth = None
        if args.truth:
            truth = json.loads(rec.with_suffix(".truth.json").read_text())
            tz = np.load(rec.with_suffix(".truth.npz"), allow_pickle=False)

        def fresh(run):
            """(rng, torch generator) of realisation ``run`` of a hand-made variant."""
            rng = np.random.default_rng([args.seed, run, 1])
            return rng, torch.Generator().manual_seed(int(rng.integers(2**31)))

        def realise(rng, gen, *, poses=None, params=None, noise=NULL_NOISE):
            ext = Extension("none", {}, {**base.base, **(params or {})})
            x0, v0 = sim.initial(1.0)
            traj = sim.rollout(ext, initial=(x0, v0 + NULL_JITTER * torch.randn(v0.shape, generator=gen)), poses=poses)
            masks = sim.render(traj, f, ext=base)
            return coarse(np.stack([corrupt_mask(m, rng, noise) for m in masks]))

        def moved(rng):
            stated = {"lambda_v": float(sim.model.params.lambda_v), "lambda_c": float(sim.model.params.lambda_c)}
            return {k: base.base.get(k, v) * (1.0 + rng.uniform(-1, 1) * NULL_PARAM_SPREAD) for k, v in stated.items()}

        def redrawn(rng):
            return ep.redrawn_poses(rng, NULL_POSE_DRIFT, NULL_POSE_DRIFT_S)

        variants = {"own_chaos": False, "poses": lambda rng: {"poses": redrawn(rng)},
                    "params": lambda rng: {"params": moved(rng)}, "analysis": True}
        if truth is not None:
            true_noise = MaskNoise(**truth["mask_noise"])
            t_true = (tz["pose_stamps_ns"] - tz["pose_stamps_ns"][0]) * 1e-9
            times = np.round(t_true * 1e9).astype(np.int64)
            true_poses = tz["true_poses"].astype(float)
            true_series = np.stack([interpolate_poses(times, true_poses[:, j], np.round(ep.pose_t * 1e9).astype(np.int64))
                                    for j in range(true_poses.shape[1])], 1)
            wp = truth["world"]["params"]
            variants["true_noise"] = lambda rng: {"noise": true_noise}
            variants["replica"] = lambda rng: {"noise": true_noise, "poses": true_series,
                                               "params": {"lambda_v": wp["lambda_v"], "lambda_c": wp["lambda_c"]}}
        row = {"recording": str(rec), "base": base.base, "base_heldout_loss": held_base, "variants": {}}
        print(f"\n{rec.name}: calibrated base {base.base or 'stated'}, held-out loss against the recording {held_base:.3f}")
        for name, make in variants.items():
            losses = []
            for run in range(args.runs):
                if isinstance(make, bool):                  # the analysis's own null, either way
                    cells = _null_cells(sims, frames, base, run, args.seed, vary=make)[0]
                else:
                    rng, gen = fresh(run)
                    cells = realise(rng, gen, **make(rng))
                losses.append(float(_held(ev.losses(base, [cells]), data)[0].mean()))
            row["variants"][name] = losses
            print(f"  {name:<11} realisations {' '.join(f'{x:.3f}' for x in losses)}   mean {np.mean(losses):.3f}"
                  f"   recording / max {held_base / max(losses):.2f}")
        results.append(row)
    if args.out:
        args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
