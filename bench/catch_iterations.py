"""The catching MPC's 8 source motions with the same liquid solved at other iteration counts,
under several float roundings (neighbour skins): is what is lost splash made by the solver?

    python bench/catch_iterations.py [--iterations 4,11] [--skins 0,0.1,0.2] [--jobs 2]

Each run is ``liquidtwin evaluate control --scene catching --quick``'s offline MPC (quick
scene, seed 0) in a model with ``iterations`` solver iterations and the cohesion of the scene
model's 4 (``reference_iterations``): 4 is the scene model, 11 the control tasks'
(``generate.world.control_model``). A skin of S·h changes only float rounding, so each skin
is another realisation of the pour's chaos (``bench/perturbed.py``). Writes
``--out`` (JSON) and appends one record per (iterations, skin) to bench/history.jsonl
(``--no-history`` to skip).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from _record import emit


def _run(work) -> dict:
    import torch

    from liquidtwin.control.catch import catching_setup, run_catch
    from liquidtwin.generate.world import MODEL_RELAXATION, model_iterations
    from liquidtwin.scenes.fill import fill_container
    from liquidtwin.sim import FluidModel
    motion, iterations, skin, fill_iterations = work
    torch.set_num_threads(1)
    setup = catching_setup(motion, True, 0)

    def model_at(k):
        return FluidModel.create(setup.h, dt=setup.dt, iterations=k, relaxation=MODEL_RELAXATION,
                                 objects=[o.grid for o in setup.objects], skin=skin * setup.h,
                                 reference_iterations=model_iterations(setup))

    model = model_at(iterations)
    k = setup.index("source")
    state, _ = fill_container(model_at(fill_iterations or iterations), torch.as_tensor(setup.poses_at(0.0)),
                              k, setup.objects[k].model, volume_ml=dict(setup.fills)["source"], settle_s=0.5)
    r = run_catch(setup, model, state)
    return {"motion": motion, "particles": int(state.x.shape[0]), "caught": r.caught, "spilled": r.spilled,
            "update_s": r.update_s}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--iterations", default="4,11", help="solver iteration counts (default: %(default)s)")
    p.add_argument("--skins", default="0,0.1,0.2", help="neighbour skins in units of h (default: %(default)s)")
    p.add_argument("--fill-iterations", type=int, default=None, metavar="K",
                   help="fill and settle the source at K iterations (default: each run's own count); more "
                        "iterations pack the same ml into fewer particles (545 at 4, 494-497 at 11)")
    p.add_argument("--jobs", type=int, default=2, help="processes (default: %(default)s)")
    p.add_argument("--out", default="bench/results/catch_iterations.json", help="results JSON (default: %(default)s)")
    p.add_argument("--no-history", action="store_true", help="do not append to bench/history.jsonl")
    a = p.parse_args()
    try:
        counts = [int(v) for v in a.iterations.split(",")]
        skins = [float(v) for v in a.skins.split(",")]
    except ValueError:
        raise SystemExit("--iterations takes whole numbers, --skins numbers, comma-separated") from None
    if not counts or not skins or min(counts) < 1 or min(skins) < 0 or (a.fill_iterations or 1) < 1 or a.jobs < 1:
        raise SystemExit("--iterations, --fill-iterations and --jobs must be >= 1 and --skins >= 0")
    from tqdm.auto import tqdm

    from liquidtwin.procs import map_jobs
    runs = []
    t0 = time.perf_counter()
    for k in counts:
        for skin in skins:
            work = [(m, k, skin, a.fill_iterations) for m in range(8)]
            res = list(tqdm(map_jobs(_run, work, a.jobs), total=8, desc=f"{k} iterations, skin {skin:g} h",
                            unit="motion"))
            caught = [r["caught"] for r in res]
            runs.append({"iterations": k, "skin_h": skin, "fill_iterations": a.fill_iterations or k, "results": res})
            emit({"what": "catch_iterations", "iterations": k, "skin_h": skin, "fill_iterations": a.fill_iterations or k,
                  "particles": sorted({r["particles"] for r in res}),
                  "caught_pct": [round(100 * c, 1) for c in caught], "at_least_98": sum(c >= 0.98 for c in caught),
                  "update_s": round(float(np.mean([r["update_s"] for r in res])), 3)}, history=not a.no_history)
    print(f"\nfilled at {a.fill_iterations or 'each run’s own'} iterations")
    print(f"\n{'iterations':>10}{'skin':>7}" + "".join(f"{m:>7}" for m in range(8)) + f"{'mean':>8}{'>=98 %':>8}")
    for r in runs:
        c = [x["caught"] for x in r["results"]]
        print(f"{r['iterations']:>10}{r['skin_h']:>6g}h" + "".join(f"{100 * x:>6.1f}%" for x in c)
              + f"{100 * np.mean(c):>7.2f}%{sum(x >= 0.98 for x in c):>6}/8")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps({"what": "catch_iterations", "wall_s": time.perf_counter() - t0, "runs": runs},
                                      indent=1))
    print(f"{time.perf_counter() - t0:.0f} s. Results in {a.out}")


if __name__ == "__main__":
    main()
