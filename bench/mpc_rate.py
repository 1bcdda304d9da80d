"""How fast the pouring MPC runs against the particle count: one gradient update (horizon
10 steps, forward and backward through SPNets) and one drain prediction (the no-gradient
rollout of a max-rate return from 60° plus 1 s of landing) per cup fill.

    python bench/mpc_rate.py --fills 30,60,120,240,345

Scene: pour_hold with a cup over a bowl (seed 0, full size: h = 1.1 cm, capacity 384 ml),
in the control tasks' model (``generate.world.control_model``: 8 solver iterations since stop
53, 5 before), filled with each volume, settled and tilted to 60° at 1 rad/s (pouring) for the timing. The controller
runs at ≥ 10 Hz while one update (plus its predictions, when due) takes ≤ 0.1 s. Appends
one JSON record per fill to bench/history.jsonl (``--no-history`` to skip).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import torch

from _record import emit
from liquidtwin.control.mpc import MPC
from liquidtwin.control.pour import lip_space, predict_landed
from liquidtwin.generate.catalog import build_setup
from liquidtwin.generate.world import control_model
from liquidtwin.scenes.fill import fill_container
from liquidtwin.sim import step


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fills", default="30,60,120,240,345", help="ml in the cup, comma-separated (default: %(default)s)")
    p.add_argument("--repeat", type=int, default=3, help="timed updates per fill, median kept (default: %(default)s)")
    p.add_argument("--horizon", type=int, default=10, help="MPC horizon, steps (default: %(default)s)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--no-history", action="store_true")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    setup = build_setup("pour_hold", np.random.default_rng(0), quick=False, source="cup", target="bowl", fraction=0.9)
    model = control_model(setup)
    src, dst = setup.index("source"), setup.index("target")
    space, lip = lip_space(setup)
    lip = lip.to(torch.float32)
    q = torch.tensor([math.radians(60.0)], dtype=torch.float64)
    for ml in (float(v) for v in a.fills.split(",")):
        state, rep = fill_container(model, torch.as_tensor(setup.poses_at(0.0)), src, setup.objects[src].model,
                                    volume_ml=ml, settle_s=0.5)
        with torch.no_grad():                 # tilt to 60° at 1 rad/s: the state while pouring
            for k in range(1, int(math.ceil(float(q[0]) / model.dt)) + 1):
                qk = torch.clamp(torch.tensor([[k * model.dt]], dtype=torch.float64), max=float(q[0]))
                state = step(model, state, space.poses(qk)[0].to(state.x))
        loss = lambda s, k, qk: (s.x - lip).norm(dim=1).mean()  # noqa: E731  (the pour loss, all particles)
        mpc = MPC(model, space, loss, horizon=a.horizon, step_size=0.5)
        mpc.plan = torch.full_like(mpc.plan, 0.5)
        times = []
        for _ in range(a.repeat):
            t0 = time.perf_counter()
            mpc.update(state, q)
            times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        predict_landed(model, state, q, space, dst, setup.objects[dst].model, rep.settled_ml / state.x.shape[0])
        predict_s = time.perf_counter() - t0
        update_s = float(np.median(times))
        emit({"what": "mpc_rate", "particles": int(state.x.shape[0]), "fill_ml": ml, "horizon": a.horizon,
              "update_s": update_s, "updates_per_s": 1.0 / update_s, "predict_s": predict_s,
              "threads": a.threads, "peak_mem_bytes": None}, not a.no_history)


if __name__ == "__main__":
    main()
