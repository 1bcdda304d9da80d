"""Is an analysis's base rollout a typical realisation of its own model? (stop 60)

    OMP_NUM_THREADS=1 .venv/bin/python bench/discrepancy_reroll.py REC.mcap --lambda-v 75 --lambda-c 0.11
        [--nulls 4] [--draws 4] [--drag 0.526 4.21] [--jitters 1e-3]

Prints the held-out coarse loss (the analysis's split and metric) of: the base rollout (the
settled fill as it is, how ``discrepancy.analyse`` predicts), the same physics re-rolled with
the initial velocities jittered (``--draws`` draws at each of ``--jitters`` m/s, default
``NULL_JITTER``), and drag extensions
(``--drag`` values), each against the recording and against the first ``--nulls`` null
realisations of the analysis (``analysis._null_cells``, seed 0). Take the calibrated λ_v, λ_c
from the analysis's report (``baseline.params``). Reads the recording only.
"""

from __future__ import annotations

import argparse

import torch


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("recording")
    p.add_argument("--lambda-v", type=float, required=True, help="the analysis's calibrated λ_v")
    p.add_argument("--lambda-c", type=float, required=True, help="the analysis's calibrated λ_c")
    p.add_argument("--nulls", type=int, default=4, help="null realisations to score against (default 4)")
    p.add_argument("--draws", type=int, default=4, help="jittered re-rolls of the base (default 4)")
    p.add_argument("--drag", type=float, nargs="*", default=[0.526, 4.21], help="drag coefficients, 1/m")
    p.add_argument("--jitters", type=float, nargs="*", default=None,
                   help="initial-velocity jitters of the re-rolls, m/s (default: the null's NULL_JITTER)")
    a = p.parse_args()
    torch.set_num_threads(1)
    from liquidtwin.discrepancy.analysis import NULL_JITTER, Options, _null_cells, prepare
    from liquidtwin.discrepancy.model import Extension
    from liquidtwin.discrepancy.residuals import cell_metrics, coarse

    opt = Options(candidates=("drag",))
    _, sims, _, frames, data, _, _ = prepare([a.recording], opt)
    base = Extension("none", {}, {"lambda_v": a.lambda_v, "lambda_c": a.lambda_c})
    sim, f = sims[0], frames[0]

    def held(model_cells, observed) -> float:
        return float(cell_metrics(model_cells, observed)["loss"][data.held[0]].mean())

    nulls = [_null_cells(sims, frames, base, r, opt.seed, True)[0] for r in range(a.nulls)]

    def row(name, traj, ext) -> None:
        cm = coarse(sim.render(traj, f, ext=ext))
        print(f"{name:<24} recording {held(cm, data.cells[0]):.3f}   nulls "
              + " ".join(f"{held(cm, n):.3f}" for n in nulls), flush=True)

    row("base", sim.rollout(base), base)
    x0, v0 = sim.initial(1.0)
    for jitter in (a.jitters if a.jitters is not None else [NULL_JITTER]):
        for k in range(a.draws):
            g = torch.Generator().manual_seed(100 + k)
            row(f"base {jitter:g} m/s {k}", sim.rollout(base, initial=(x0, v0 + jitter * torch.randn(v0.shape, generator=g))), base)
    for c in a.drag:
        e = Extension("drag", {"c": c}, base.base)
        row(f"drag {c:g}", sim.rollout(e), e)


if __name__ == "__main__":
    main()
