"""Train the catching policy through SPNets (thesis §8.3.4; ``control.policy``).

    python -m liquidtwin.control.train_policy --out catch_policy.pt

1. Demonstrations: the catching MPC runs on the training source motions (default 0–3, the
   pours towards −x, counter-clockwise as in the thesis) and keeps the state before every
   step (cached as ``.npz`` in ``--demos``; a rerun with the same settings reads them back).
2. Training: ``control.policy.train`` — per iteration one sampled step of every
   demonstration, the catcher placed at the demonstration's x plus noise, a rollout of the
   policy through the model, one Adam step with the gradient through the rollout.

Writes the policy file (``torch.load(weights_only=True)``) and ``<out>.json`` with the loss
curve. Evaluate with ``liquidtwin evaluate control --scene catching --controller policy``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from .policy import CatchPolicy, Demonstration, parameter_count, save_policy, train


def _episode(motion: int, quick: bool, seed: int):
    from ..generate.world import model_for
    from ..scenes.fill import fill_container
    from .catch import catching_setup
    setup = catching_setup(motion, quick, seed)
    model = model_for(setup)
    k = setup.index("source")
    state, _ = fill_container(model, torch.as_tensor(setup.poses_at(0.0)), k, setup.objects[k].model,
                              volume_ml=dict(setup.fills)["source"], settle_s=0.5)
    return setup, model, state


def _demo_worker(work) -> dict:
    from .policy import demonstrations
    motion, quick, seed, horizon, step_size = work
    torch.set_num_threads(1)
    setup, model, state = _episode(motion, quick, seed)
    d = demonstrations(setup, model, state, horizon=horizon, step_size=step_size)
    return {"motion": motion, "x": np.stack([s.x.numpy() for s in d.states]),
            "v": np.stack([s.v.numpy() for s in d.states]), "ids": d.states[0].ids.numpy(),
            "poses": np.stack([np.asarray(s.poses, np.float64) for s in d.states]),
            "t": np.array([s.t for s in d.states]), "xs": d.xs, "aims": d.aims}


def load_demos(motions: list[int], quick: bool, seed: int, horizon: int, step_size: float, cache: Path | None,
               jobs: int, progress: bool = True) -> tuple[list[Demonstration], object]:
    """The demonstrations of ``motions`` (and the model they ran in), from the cache or by MPC."""
    from tqdm.auto import tqdm

    from ..procs import map_jobs
    from ..sim import FluidState

    def path(m):
        return None if cache is None else \
            cache / f"catch_demo2_m{m}_s{seed}_{'quick' if quick else 'full'}_h{horizon}_step{step_size:g}.npz"

    todo = [m for m in motions if path(m) is None or not path(m).is_file()]
    raw = {}
    work = [(m, quick, seed, horizon, step_size) for m in todo]
    for r in tqdm(map_jobs(_demo_worker, work, jobs), total=len(work), desc="MPC demonstrations", unit="motion",
                  disable=not progress):
        raw[r["motion"]] = r
        if cache is not None:
            cache.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(path(r["motion"]), **{k: v for k, v in r.items() if k != "motion"})
    demos, model = [], None
    for m in motions:
        r = raw.get(m)
        if r is None:
            with np.load(path(m), allow_pickle=False) as z:
                r = {k: z[k] for k in z.files}
        setup, model, state = _episode(m, quick, seed)
        ids = torch.as_tensor(r["ids"])
        states = [FluidState(torch.as_tensor(x), torch.as_tensor(v), ids, torch.as_tensor(P).to(state.poses),
                             float(t)) for x, v, P, t in zip(r["x"], r["v"], r["poses"], r["t"])]
        demos.append(Demonstration(setup, states, np.asarray(r["xs"]), np.asarray(r["aims"])))
    return demos, model


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m liquidtwin.control.train_policy",
                                description="Train the catching policy by backpropagation through SPNets rollouts "
                                            "from MPC demonstrations (thesis §8.3.4); writes a weights_only file.")
    p.add_argument("--out", type=Path, required=True, help="policy file to write (.pt)")
    p.add_argument("--motions", default="0,1,2,3", metavar="K[,K]",
                   help="training source motions (default: %(default)s, the pours towards −x)")
    p.add_argument("--iterations", type=int, default=120, help="Adam steps (default: %(default)s; thesis 1200)")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (default: %(default)s; thesis 2.5e-5)")
    p.add_argument("--rollout", type=int, default=3, help="policy steps per rollout (default: %(default)s)")
    p.add_argument("--per-demo", type=int, default=4,
                   help="sampled steps per demonstration per iteration (default: %(default)s; thesis 1)")
    p.add_argument("--noise", type=float, default=0.05, help="catcher start noise, m (default: %(default)s)")
    p.add_argument("--active-share", type=float, default=0.5,
                   help="share of the sampled steps drawn where liquid falls (default: %(default)s; thesis: "
                        "uniform draws)")
    p.add_argument("--pool", type=int, default=2, help="average pool after the conv (default: %(default)s; "
                                                       "1 = the thesis's 4.7 M-weight network)")
    p.add_argument("--mirror", action="store_true",
                   help="a network odd under a left-right flip of its image (CatchPolicy(mirror=True)): "
                        "the x -> -x symmetry of the task built in")
    p.add_argument("--full", action="store_true", help="the full-size scene (default: the quick one)")
    p.add_argument("--horizon", type=int, default=10, help="demonstrating MPC's horizon (default: %(default)s)")
    p.add_argument("--step-size", type=float, default=0.1, help="demonstrating MPC's step (default: %(default)s)")
    p.add_argument("--demos", type=Path, default=Path("catch-demos"), metavar="DIR",
                   help="cache of MPC demonstrations (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="scene draw and sampling (default: %(default)s)")
    p.add_argument("--jobs", type=int, default=2, help="demonstrations run in parallel (default: %(default)s)")
    p.add_argument("--threads", type=int, default=1, help="torch threads for training (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")
    a = p.parse_args(argv)
    try:
        motions = [int(m) for m in a.motions.split(",") if m.strip()]
    except ValueError:
        p.error(f"--motions takes source motions 0-7, got {a.motions!r}")
    if not motions or any(not 0 <= m < 8 for m in motions):
        p.error(f"--motions takes source motions 0-7, got {a.motions!r}")
    t0 = time.perf_counter()
    demos, model = load_demos(motions, not a.full, a.seed, a.horizon, a.step_size, a.demos, a.jobs,
                              progress=not a.no_progress)
    t_demo = time.perf_counter() - t0
    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    policy = CatchPolicy(pool=a.pool, mirror=a.mirror)
    log = train(policy, model, demos, iterations=a.iterations, lr=a.lr, rollout=a.rollout, noise_m=a.noise,
                active_share=a.active_share, per_demo=a.per_demo, seed=a.seed, progress=not a.no_progress)
    meta = {"motions": motions, "quick": not a.full, "seed": a.seed, "iterations": a.iterations, "lr": a.lr,
            "rollout": a.rollout, "noise_m": a.noise, "active_share": a.active_share, "per_demo": a.per_demo,
            "parameters": parameter_count(policy)}
    save_policy(a.out, policy.eval(), meta)
    curve = a.out.with_suffix(".json")
    curve.write_text(json.dumps({**meta, "demo_s": t_demo, "train_s": log.seconds, "losses": log.losses}))
    first, last = np.mean(log.losses[:20]), np.mean(log.losses[-20:])
    print(f"wrote {a.out} ({parameter_count(policy):,} weights) and {curve}: demonstrations {t_demo:.0f} s, "
          f"training {log.seconds:.0f} s; loss (mean of first / last 20 iterations) {first:.4f} → {last:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
