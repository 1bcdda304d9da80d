"""The system-identification loss and its λ_v gradient along a line of λ_v values.

    OMP_NUM_THREADS=1 .venv/bin/python bench/sysid_gradient_scan.py --lambda-c 0.1 --lambda-v 30

Simulates the quick ladle sequence with the true (λ_c, λ_v), draws ``--starts`` start states
(fixed seed), and at each λ_v of ``--values`` (λ_c held at its truth) evaluates the fit's
batch loss and its gradient with respect to λ_v on consecutive batches of 8 starts, exactly
as one fit iteration does (``sysid.fit.batch_loss``). Prints per λ_v: the mean loss, the mean
and spread of the batch gradients, and the share of batches whose gradient points towards the
truth. A loss that identifies λ_v has its minimum at the truth and gradients that point to
it from both sides. Appends one record to bench/history.jsonl (``--no-history``: not).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from _record import emit


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--lambda-c", type=float, default=0.1, help="true λ_c (default: %(default)s)")
    p.add_argument("--lambda-v", type=float, default=30.0, help="true λ_v (default: %(default)s)")
    p.add_argument("--loss", default="projection", choices=("l1", "projection"))
    p.add_argument("--horizon", type=int, default=2)
    p.add_argument("--starts", type=int, default=64, help="start states, a multiple of 8 (default: %(default)s)")
    p.add_argument("--values", default="20,30,45,60,80", help="λ_v values to scan (default: %(default)s)")
    p.add_argument("--seed", type=int, default=1, help="seed of the start states (default: %(default)s)")
    p.add_argument("--no-history", action="store_true",
                   help="do not append to bench/history.jsonl (e.g. when PYTHONPATH points at another version)")
    args = p.parse_args()
    if args.starts < 8 or args.starts % 8:
        raise SystemExit("--starts must be a positive multiple of 8 (the fit's batch)")
    from liquidtwin.sysid import FitConfig, simulate_sequence
    from liquidtwin.sysid.fit import SCALES, Views, batch_loss
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    seq = simulate_sequence("ladle", {"lambda_c": args.lambda_c, "lambda_v": args.lambda_v}, seed=0, quick=True)
    print(f"quick ladle: {seq.particles} particles, {seq.steps} steps ({time.perf_counter() - t0:.0f} s)")
    cfg = FitConfig(loss=args.loss, horizon=args.horizon)
    starts = np.random.default_rng(args.seed).integers(0, seq.steps - args.horizon + 1, size=args.starts)
    views = Views(seq)
    rows = []
    for lv in (float(v) for v in args.values.split(",")):
        theta = torch.tensor(lv / SCALES["lambda_v"], dtype=torch.float64, requires_grad=True)
        losses, grads = [], []
        for k in range(0, args.starts, 8):
            model = seq.model.with_params(lambda_c=torch.tensor(args.lambda_c, dtype=torch.float64),
                                          lambda_v=theta * SCALES["lambda_v"])
            loss = batch_loss(seq, model, starts[k:k + 8], cfg, views=views)
            g, = torch.autograd.grad(loss, theta)
            losses.append(float(loss.detach()))
            grads.append(float(g) / SCALES["lambda_v"])
        g = np.asarray(grads)
        toward = np.sign(args.lambda_v - lv)          # descending moves λ_v by −gradient
        share = float(np.mean(-np.sign(g) == toward)) if toward else None
        rows.append({"lambda_v": lv, "loss": float(np.mean(losses)), "grad_mean": float(g.mean()),
                     "grad_sd": float(g.std()), "toward_truth": share})
        print(f"λ_v {lv:6.1f}  loss {np.mean(losses):.3e}  dloss/dλ_v mean {g.mean():+.2e} sd {g.std():.2e}  "
              f"batches pointing to the truth {'—' if share is None else f'{share:.2f}'}", flush=True)
    emit({"what": "sysid_gradient_scan", "truth": {"lambda_c": args.lambda_c, "lambda_v": args.lambda_v},
          "loss": args.loss, "horizon": args.horizon, "starts": args.starts, "rows": rows},
         history=not args.no_history)


if __name__ == "__main__":
    main()
