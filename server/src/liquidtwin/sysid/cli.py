"""``liquidtwin fit``: estimate fluid parameters through the differentiable simulator.

The data is a sequence of true particle states with the objects' poses: simulated on the
spot from a catalogue scene and true parameters (``--scene ladle --truth lambda_c=0.1,
lambda_v=60``; ``--save-data`` keeps it) or read back (``--data SEQ.npz``). Prints the
estimates with their spread and, when the truth is known, the relative errors; ``--out DIR``
writes fit.json and convergence.png.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

HELP = "estimate fluid parameters (λ_c, λ_v, …) by gradient descent through SPNets, from particle tracks or images"


def _values(text: str, what: str) -> dict:
    out = {}
    for item in filter(None, (s.strip() for s in (text or "").split(","))):
        name, eq, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise SystemExit(f"liquidtwin fit: {what} takes NAME=VALUE[,NAME=VALUE], got {item!r}") from None
        if not eq:
            raise SystemExit(f"liquidtwin fit: {what} takes NAME=VALUE[,NAME=VALUE], got {item!r}")
    return out


def configure(p) -> None:
    from .fit import LOSSES, SCALES, FitConfig
    src = p.add_argument_group("data (one of)")
    src.add_argument("--data", type=Path, metavar="SEQ.npz", help="a saved sequence (see --save-data)")
    src.add_argument("--scene", default="ladle", help="simulate this catalogue scene (default: %(default)s)")
    src.add_argument("--truth", default="lambda_c=0.1,lambda_v=60", metavar="P=V[,P=V]",
                     help="true parameters of the simulated sequence (default: %(default)s)")
    src.add_argument("--seed", type=int, default=0, help="scene draw (default: %(default)s)")
    src.add_argument("--quick", action="store_true", help="the quick variant of the scene (fewer particles)")
    src.add_argument("--steps", type=int, default=None, metavar="N", help="simulate only N steps")
    src.add_argument("--save-data", type=Path, metavar="SEQ.npz", help="keep the simulated sequence")
    fit = p.add_argument_group("fit")
    fit.add_argument("--params", default="lambda_c,lambda_v", metavar="P[,P]",
                     help=f"parameters to estimate, any of {', '.join(SCALES)} (default: %(default)s)")
    fit.add_argument("--init", default="", metavar="P=V[,P=V]", help="starting values (default: the model's defaults)")
    fit.add_argument("--loss", choices=LOSSES, default="l1",
                     help="l1: positions and velocities, needs particle correspondence; projection: camera "
                          "images, needs none (default: %(default)s)")
    fit.add_argument("--iterations", type=int, default=300, help="Adam iterations (default: %(default)s)")
    fit.add_argument("--batch", type=int, default=8, help="sampled states per iteration (default: %(default)s)")
    fit.add_argument("--horizon", type=int, default=2, help="steps rolled out from each (default: %(default)s)")
    fit.add_argument("--lr", type=float, default=FitConfig.lr, help="Adam learning rate, in units of each "
                                                                   "parameter's usual size (default: %(default)s)")
    fit.add_argument("--lr-final", type=float, default=FitConfig.lr_final, metavar="F",
                     help="anneal the learning rate (cosine) to F x --lr by the last iteration; the thesis: "
                          "--lr 0.01 --lr-final 1, constant (default: %(default)s)")
    p.add_argument("--out", type=Path, metavar="DIR", help="write fit.json and convergence.png here")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def run(args) -> int:
    import torch

    from .data import SequenceError, load_sequence, save_sequence, simulate_sequence
    from .fit import FitConfig, fit
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    try:
        cfg = FitConfig(params=tuple(s.strip() for s in args.params.split(",") if s.strip()),
                        init=_values(args.init, "--init"), loss=args.loss, batch=args.batch,
                        horizon=args.horizon, lr=args.lr, lr_final=args.lr_final, iterations=args.iterations,
                        seed=args.seed)
        t0 = time.perf_counter()
        if args.data is not None:
            seq = load_sequence(args.data)
        else:
            seq = simulate_sequence(args.scene, _values(args.truth, "--truth"), seed=args.seed, quick=args.quick,
                                    steps=args.steps, progress=not args.no_progress)
            if args.save_data is not None:
                save_sequence(seq, args.save_data)
        data_s = time.perf_counter() - t0
        res = fit(seq, cfg, progress=not args.no_progress)
    except (SequenceError, ValueError) as exc:
        print(f"liquidtwin fit: {exc}", file=sys.stderr)
        return 2
    print(f"{seq.scene}: {seq.particles} particles, {seq.steps} steps (data {data_s:.1f} s); "
          f"{cfg.loss} loss, {cfg.iterations} iterations in {res.wall_s:.1f} s "
          f"({res.particle_steps_per_s:,.0f} particle-steps/s forward+backward)")
    err = res.relative_error(seq.truth) if set(res.params) <= set(seq.truth) else {}
    for p in res.params:
        line = f"  {p:<13} {res.values[p]:.5g} ± {res.std[p]:.2g}"
        if p in err:
            line += f"   truth {seq.truth[p]:g}, error {100 * err[p]:.2f} %"
        print(line)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        doc = res.as_dict() | {"truth": seq.truth, "relative_error": err, "scene": seq.scene, "seed": seq.seed,
                               "quick": seq.quick, "history": res.history.tolist(), "losses": res.losses.tolist()}
        (args.out / "fit.json").write_text(json.dumps(doc, indent=1) + "\n")
        _plot(args.out / "convergence.png", res, seq.truth)
        print(f"wrote {args.out / 'fit.json'} and convergence.png")
    return 0


def _plot(path: Path, res, truth: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(res.params) + 1, 1, figsize=(6, 2.2 * (len(res.params) + 1)), sharex=True)
    for ax, (i, p) in zip(axes, enumerate(res.params)):
        ax.plot(res.history[:, i], label="estimate")
        if p in truth:
            ax.axhline(truth[p], color="k", ls="--", lw=0.8, label="truth")
        ax.set_ylabel(p)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[-1].semilogy(res.losses)
    axes[-1].set_ylabel(f"{res.config.loss} loss")
    axes[-1].set_xlabel("iteration")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
