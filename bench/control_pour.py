"""Pour a target volume by MPC through SPNets (``liquidtwin.control.pour``) and report what
reached the bowl, what was spilled, and the wall time per MPC update.

    python bench/control_pour.py --fill 60 --targets 20 --step-size 0.5

Quick pour_hold scene (cup → bowl, seed 0), the cup (``--cup-scale``: the pouring
benchmark's, shrunk with the quick liquid) filled with ``--fill`` ml and settled.
What is spilled is split into liquid that was in the bowl at some step and left it again
(over the rim) and liquid that never got in. Appends one JSON record per target to
bench/history.jsonl (``--no-history`` to skip).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from _record import emit
from liquidtwin.control.pour import LOOKAHEAD_S, run_pour
from liquidtwin.evaluate.control import POUR_CUP_SCALE
from liquidtwin.generate.catalog import build_setup
from liquidtwin.generate.world import control_model
from liquidtwin.scenes.fill import fill_container
from liquidtwin.scenes.liquid_level import held


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fill", type=float, default=60.0, help="ml in the cup (default: %(default)s)")
    p.add_argument("--targets", default="20", help="ml to pour, comma-separated (default: %(default)s)")
    p.add_argument("--step-size", type=float, default=0.5, help="MPC step, rad/s (default: %(default)s)")
    p.add_argument("--no-anticipate", action="store_true",
                   help="switch when the asked amount has left the cup (the thesis's rule) instead of "
                        "predicting what still flows while the cup turns back")
    p.add_argument("--approach-rate", type=float, default=None, metavar="RAD_S",
                   help="cap on the forward tilt rate from 20 deg on, rad/s (default: none, the full 2 rad/s)")
    p.add_argument("--lookahead", type=float, default=LOOKAHEAD_S, metavar="S",
                   help="the pull to the lip scores each particle S seconds ahead at its velocity (default: "
                        "%(default)s; 0: the thesis's loss)")
    p.add_argument("--max-seconds", type=float, default=6.0, help="pour length limit, s (default: %(default)s)")
    p.add_argument("--trace", type=float, default=None, metavar="S",
                   help="every S seconds print the tilt and where the liquid is (cup, bowl, neither)")
    p.add_argument("--cup-scale", type=float, default=POUR_CUP_SCALE,
                   help="the cup's lengths × this (default: %(default).3f, as liquidtwin evaluate control "
                        "--scene pouring; 1: the full-size cup)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--no-history", action="store_true")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    setup = build_setup("pour_hold", np.random.default_rng(0), quick=True, source="cup", target="bowl", fraction=0.9,
                        source_scale=a.cup_scale)
    model = control_model(setup)
    k = setup.index("source")
    state, rep = fill_container(model, torch.as_tensor(setup.poses_at(0.0)), k, setup.objects[k].model,
                                volume_ml=a.fill, settle_s=0.5)
    mlpp = rep.settled_ml / state.x.shape[0]
    print(f"cup: {state.x.shape[0]} particles, {rep.settled_ml:.1f} ml settled")
    src, dst = setup.index("source"), setup.index("target")
    every = None if a.trace is None else max(1, int(round(a.trace / model.dt)))

    seen = {}

    def trace(i, s, q, ctrl):
        in_bowl = held(model, s, dst, setup.objects[dst].model)[0]
        seen["ever"] = seen["ever"] | set(s.ids[torch.as_tensor(in_bowl)].tolist())
        seen["last"] = s
        if every is None or i % every:
            return
        cup = int(held(model, s, src, setup.objects[src].model)[0].sum()) * mlpp
        bowl = int(in_bowl.sum()) * mlpp
        print(f"  {(i + 1) * model.dt:5.2f} s  tilt {np.degrees(float(q)):5.1f} deg  cup {cup:5.1f}  bowl {bowl:5.1f}  "
              f"neither {rep.settled_ml - cup - bowl:5.1f} ml{'  (returning)' if ctrl.done else ''}", flush=True)

    for target in (float(t) for t in a.targets.split(",")):
        t0 = time.perf_counter()
        seen.update(ever=set(), last=state)
        r = run_pour(setup, model, state, target, mlpp, step_size=a.step_size, anticipate=not a.no_anticipate,
                     progress=a.trace is None, approach_rate=a.approach_rate, max_seconds=a.max_seconds,
                     lookahead_s=a.lookahead, on_step=trace)
        last = seen["last"]
        out = ~(held(model, last, src, setup.objects[src].model)[0] | held(model, last, dst, setup.objects[dst].model)[0])
        spilled_ids = last.ids[torch.as_tensor(out)].tolist()
        after = sum(1 for i in spilled_ids if i in seen["ever"])
        rec = {"what": "mpc_pour", "particles": int(state.x.shape[0]), "cup_scale": a.cup_scale, "target_ml": target,
               "poured_ml": r.poured_ml, "left_ml": r.left_ml, "spilled_ml": r.spilled_ml,
               "spilled_after_entering_ml": after * mlpp, "spilled_never_entered_ml": (len(spilled_ids) - after) * mlpp,
               "switched_s": r.switched_s, "anticipate": not a.no_anticipate, "approach_rate": a.approach_rate,
               "lookahead_s": a.lookahead,
               "max_angle_deg": float(np.max(r.angles_deg)),
               "update_s": r.update_s, "wall_s": time.perf_counter() - t0, "peak_mem_bytes": None}
        emit(rec, not a.no_history)


if __name__ == "__main__":
    main()
