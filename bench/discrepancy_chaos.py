"""How far two runs of one model are apart: the discrepancy analysis's held-out loss between
the base model's rollout and jittered realisations of it, against the recording's.

    OMP_NUM_THREADS=1 .venv/bin/python bench/discrepancy_chaos.py [--seed 4] [--effect drag]

The recording: quick ``pour_partial``, cup 90 %, the effect planted (value drawn from the
seed). The model is the *default* base (stated parameters, not calibrated), with the
analysis's pose smoothing and extra iterations. Six realisations (1 mm/s of initial-velocity
jitter, the null's mid-range mask noise) are scored against the unjittered rollout, as the
null test does; then a 3-rollout mean is used as the model, and drag at 2, 4 and 6 1/m is
scored the same way. Prints the held-out (and fitting) losses and the per-frame ones.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--effect", default="drag", help="planted effect ('none' for none)")
    p.add_argument("--scene", default="pour_partial")
    args = p.parse_args()
    import torch
    torch.set_num_threads(1)
    import liquidtwin.generate.generator as gen
    from liquidtwin.discrepancy.analysis import NULL_NOISE, Options, prepare
    from liquidtwin.discrepancy.model import Extension
    from liquidtwin.discrepancy.residuals import cell_metrics, coarse
    from liquidtwin.sensors.masks import corrupt_mask

    rec = Path(tempfile.mkdtemp()) / "rec.mcap"
    gen.generate(args.scene, rec, effects=[(args.effect, None)] if args.effect != "none" else [], seed=args.seed,
                 quick=True, choices={"source": "cup", "fraction": 0.9})
    _, sims, ev, frames, data, _, _ = prepare([rec], Options())
    sim, f, obs, held = sims[0], frames[0], data.cells[0], data.held[0]
    base = Extension()
    ref = ev.cells(base)[0]

    def loss(a, b):
        return cell_metrics(a, b)["loss"]

    def realise(ext, gen_, noise_rng=None):
        x0, v0 = sim.initial(1.0)
        traj = sim.rollout(ext, initial=(x0, v0 + 1e-3 * torch.randn(v0.shape, generator=gen_)))
        masks = sim.render(traj, f, ext=ext)
        if noise_rng is not None:
            masks = np.stack([corrupt_mask(m, noise_rng, NULL_NOISE) for m in masks])
        return coarse(masks)

    rng, jitter = np.random.default_rng(0), torch.Generator().manual_seed(0)
    real = [realise(base, jitter, rng) for _ in range(6)]
    np.set_printoptions(linewidth=200, precision=2, suppress=True)
    print("recording vs base: held-out", loss(ref, obs)[held].mean().round(3), "fitting", loss(ref, obs)[~held].mean().round(3))
    for k, r in enumerate(real):
        print(f"realisation {k} vs base: held-out", loss(ref, r)[held].mean().round(3),
              "| vs the recording", loss(r, obs)[held].mean().round(3))
    print("per frame, recording vs base", loss(ref, obs))
    print("per frame, realisation 0 vs base", loss(ref, real[0]))
    j2 = torch.Generator().manual_seed(5)

    def mean_of_three(ext):
        return np.mean([realise(ext, j2).astype(float) for _ in range(3)], 0)

    m = mean_of_three(base)
    print("3-rollout mean as the model: recording", loss(m, obs)[held].mean().round(3),
          "realisations", [float(loss(m, r)[held].mean().round(3)) for r in real])
    for c in (2.0, 4.0, 6.0):
        d = mean_of_three(Extension("drag", {"c": c}))
        print(f"drag {c}, 3-rollout mean: held-out", loss(d, obs)[held].mean().round(3), "fitting", loss(d, obs)[~held].mean().round(3))


if __name__ == "__main__":
    main()
