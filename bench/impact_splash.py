"""How much of a falling column of liquid the solver throws back out of a cup, by impact
speed and solver iterations — the measurement behind ``sim.iterations_for_impact``.

    python bench/impact_splash.py [--seeds 5] [--max-correction S] [--out bench/results/impact_splash.json]

A column of liquid (3 cm across, 12 cm long, 470 particles of the quick scenes' spacing)
starts 5 mm above the rim of the catching scene's cup, moving straight down at v, and falls
into 25 ml already resting in the cup. After 0.8 s the share of all the liquid that is no
longer in the cup is counted. Each (v, K) is the mean over ``--seeds`` columns shifted
sideways by up to 0.3 spacing. K solver iterations solve the *same* liquid
(``reference_iterations`` = 4, the quick scenes' count): only how well the density
constraint is solved changes, so what falls with K is a solver error, not the liquid.
``--max-correction S`` caps every solver iteration's move at S rest spacings
(``FluidModel.max_correction``; the control tasks' model uses 0.5).

Why: a particle arriving at v moves v·dt into the liquid below in one step (2.75 rest
spacings at 2 m/s and 120 Hz). Too few iterations leave that overlap half solved and the
next step turns it into velocity: splashes leave faster than they came in (catching motion
7 at 4 iterations: in at 1.8-2.3 m/s, out at up to 4.1 m/s). Writes the table as JSON and
appends one record to bench/history.jsonl (``--no-history`` to skip).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from _record import emit
from liquidtwin.control.catch import catching_setup
from liquidtwin.generate.world import MODEL_RELAXATION
from liquidtwin.scenes.fill import fill_container
from liquidtwin.scenes.liquid_level import held
from liquidtwin.sim import FluidModel, iterations_for_impact, step
from liquidtwin.sim.packing import lattice
from liquidtwin.sim.pbf import make_state

SPEEDS = (1.0, 1.5, 2.0, 2.5, 3.0)
ITERATIONS = (4, 6, 8, 10, 12, 16)
REFERENCE = 4
POOL_ML = 25.0
SECONDS = 0.8


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=5, help="columns per (speed, iterations) (default: %(default)s)")
    p.add_argument("--out", default="bench/results/impact_splash.json", help="results JSON (default: %(default)s)")
    p.add_argument("--no-history", action="store_true", help="do not append to bench/history.jsonl")
    p.add_argument("--max-correction", type=float, default=None, metavar="S",
                   help="cap each solver iteration's move at S rest spacings (default: no cap, SPNets as published)")
    a = p.parse_args()
    if a.max_correction is not None and not a.max_correction > 0:
        raise SystemExit("--max-correction must be > 0 rest spacings")
    if a.seeds < 1:
        raise SystemExit("--seeds must be >= 1")
    torch.set_num_threads(1)
    setup = catching_setup(0, True, 0)
    dst, src = setup.index("catcher"), setup.index("source")
    poses = torch.as_tensor(np.array(setup.poses_at(0.0), float))
    poses[src, 0] += 1.0                                     # the pouring cup out of the way
    cup = setup.objects[dst].model
    centre = poses[dst, :3].numpy()

    def model(k: int) -> FluidModel:
        m = FluidModel.create(setup.h, dt=setup.dt, iterations=k, relaxation=MODEL_RELAXATION,
                              objects=[o.grid for o in setup.objects], reference_iterations=REFERENCE)
        return m if a.max_correction is None else m.replace(max_correction=a.max_correction * m.spacing)

    pool, _ = fill_container(model(REFERENCE), poses, dst, cup, volume_ml=POOL_ML, settle_s=0.5)
    spacing = model(REFERENCE).spacing
    col = lattice(centre + [-0.015, 0.0, -0.015], centre + [0.015, 0.12, 0.015], spacing)
    col = col[(col[:, 0] - centre[0]) ** 2 + (col[:, 2] - centre[2]) ** 2 <= 0.015 ** 2]
    col[:, 1] += cup.rim_height + 0.005
    x0 = np.concatenate([pool.x.numpy(), col])
    t0 = time.perf_counter()
    rows = []
    bar = tqdm(total=len(SPEEDS) * len(ITERATIONS) * a.seeds, desc="impacts", unit="run")
    for v in SPEEDS:
        v0 = np.concatenate([pool.v.numpy(), np.tile([0.0, -v, 0.0], (len(col), 1))])
        out = {}
        for k in ITERATIONS:
            m, shares = model(k), []
            for seed in range(a.seeds):
                x = x0.copy()
                x[len(pool.x):] += np.random.default_rng(seed).uniform(-0.3, 0.3, 3) * spacing
                s = make_state(x, v0, poses)
                for _ in range(int(round(SECONDS / m.dt))):
                    s = step(m, s, poses.to(s.x))
                shares.append(1.0 - float(np.mean(held(m, s, dst, cup)[0])))
                bar.update()
            out[k] = float(np.mean(shares))
        rows.append({"speed_m_s": v, "penetration_spacings": v * setup.dt / spacing, "thrown_out": out,
                     "rule_iterations": iterations_for_impact(v, setup.dt, spacing)})
    bar.close()
    print(f"\n{len(pool.x)} particles resting, a column of {len(col)} falling; share thrown out of the cup, %")
    print(f"{'v m/s':>6}{'v·dt/spacing':>14}" + "".join(f"{'K=' + str(k):>8}" for k in ITERATIONS) + f"{'rule K':>8}")
    for r in rows:
        print(f"{r['speed_m_s']:>6.1f}{r['penetration_spacings']:>14.2f}"
              + "".join(f"{100 * r['thrown_out'][k]:>8.2f}" for k in ITERATIONS) + f"{r['rule_iterations']:>8}")
    doc = {"what": "impact_splash", "max_correction_spacings": a.max_correction, "pool_particles": len(pool.x), "column_particles": len(col), "seeds": a.seeds,
           "reference_iterations": REFERENCE, "dt": setup.dt, "spacing": spacing, "seconds": SECONDS,
           "wall_s": time.perf_counter() - t0, "rows": [{**r, "thrown_out": {str(k): f for k, f in r["thrown_out"].items()}}
                                                         for r in rows]}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(doc, indent=1))
    emit({"what": "impact_splash", "seeds": a.seeds, "max_correction_spacings": a.max_correction,
          "thrown_out_pct_at_2m_s": {str(k): round(100 * rows[2]["thrown_out"][k], 2) for k in ITERATIONS}},
         history=not a.no_history)
    print(f"{doc['wall_s']:.0f} s. Results in {a.out}")


if __name__ == "__main__":
    main()
