"""Where does the liquid the plate MPC loses go? Follow every particle through the quick plate
scene, and replay the executed tilts with shorter PBF steps.

    OMP_NUM_THREADS=1 python bench/plate_misses.py [--targets 0,1,…] [--substeps 1,2,4] [--jobs 2]
        [--full] [--lookahead S]

For each target bowl (quick ``plate_tilt`` scene, or the full one with ``--full``; seed 0, the
MPC of ``liquidtwin evaluate control [--quick] [--lookahead S]``): the particles the target
bowl holds at the end, those it held at some step and lost ("splashed out": in the bowl's
cavity, then over its rim), and those it never held ("missed"); the horizontal speed of each
particle at the first step the bowl holds it; and the first step at which a particle the bowl
held leaves it.

Then the tilt trajectory the MPC executed is replayed open loop by the same model with dt / n
for each ``--substeps`` n (the tilt interpolated linearly between executed steps): the share
that ends in the target bowl. PBF applies its position corrections per step, so a shorter step
is not only a finer one; the replay measures how much the outcome depends on it.

Writes ``--out`` (JSON, every number) and appends one record per target to bench/history.jsonl.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
from pathlib import Path

import numpy as np
import torch

from _record import emit

RESULTS = Path(__file__).resolve().parent / "results" / "plate_misses_quick.json"


def _in_bowl(setup, model, state, target: int) -> np.ndarray:
    """(N,) bool by particle id: held by bowl ``target``."""
    from liquidtwin.scenes.liquid_level import held
    k = setup.index(f"bowl{target}")
    mask = held(model, state, k, setup.objects[k].model)[0]
    out = np.zeros(int(state.ids.max()) + 1, bool)
    out[state.ids.numpy()] = mask
    return out


def replay(setup, model, state, target: int, tilts_deg: np.ndarray, substeps: int) -> float:
    """Share of the particles in bowl ``target`` after replaying ``tilts_deg`` (steps, 2) open
    loop with PBF steps of dt / ``substeps``."""
    from liquidtwin.control.plate import plate_space
    from liquidtwin.sim import step
    space = plate_space(setup)
    fine = model.replace(dt=model.dt / substeps)
    q_prev = torch.zeros(2, dtype=torch.float64)
    with torch.no_grad():
        for q_deg in tilts_deg:
            q = torch.as_tensor(np.radians(q_deg), dtype=torch.float64)
            for j in range(1, substeps + 1):
                qj = q_prev + (q - q_prev) * j / substeps
                state = step(fine, state, space.poses(qj[None])[0].to(state.x.dtype))
            q_prev = q
    return float(_in_bowl(setup, fine, state, target).mean())


def run_target(work) -> dict:
    target, substeps, quick, lookahead = work
    from liquidtwin.control.plate import plate_scene, run_plate
    torch.set_num_threads(1)
    setup, model, state = plate_scene(0, quick)
    n = int(state.x.shape[0])
    held_by_step, speed_by_step = [], []

    def follow(k, s):
        held_by_step.append(_in_bowl(setup, model, s, target))
        v = np.zeros((int(s.ids.max()) + 1, 3))
        v[s.ids.numpy()] = s.v.detach().double().numpy()
        speed_by_step.append(np.hypot(v[:, 0], v[:, 2]))

    r = run_plate(setup, model, state, target, on_step=follow, lookahead_s=lookahead)
    H = np.stack(held_by_step)                      # (steps, ids)
    ever, end = H.any(0), H[-1]
    first = np.argmax(H, 0)
    entry_speed = np.array([speed_by_step[first[i]][i] for i in np.nonzero(ever)[0]])
    lost = ever & ~end
    left_at = [int(np.nonzero(H[:, i])[0][-1]) + 1 for i in np.nonzero(lost)[0]]
    return {"target": target, "particles": n, "dt_s": model.dt, "caught": r.caught,
            "splashed_out": int(lost.sum()), "missed": int((~ever).sum()),
            "entry_speed_m_s": {"p10": float(np.percentile(entry_speed, 10)), "median": float(np.median(entry_speed)),
                                "p90": float(np.percentile(entry_speed, 90))} if len(entry_speed) else None,
            "entry_steps": [int(first[ever].min()), int(first[ever].max())] if ever.any() else None,
            "first_splash_step": min(left_at) if left_at else None,
            # run_plate never changes ``state`` (steps return new states): every replay starts from it
            "replay_in_target": {str(m): replay(setup, model, state, target, r.tilts_deg, m) for m in substeps}}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--targets", default="0,1,2,3,4,5,6,7", help="target bowls, comma-separated (default: all 8)")
    p.add_argument("--substeps", default="1,2,3,4,6,8",
                   help="replay the executed tilts with dt / n for each n, comma-separated (default: %(default)s)")
    p.add_argument("--jobs", type=int, default=2, help="targets run in parallel (default: %(default)s)")
    p.add_argument("--full", action="store_true",
                   help="the full scene (1,092 particles; ~1 min a target, and a replay costs as much per n)")
    p.add_argument("--lookahead", type=float, default=None, metavar="S",
                   help="the plate loss's lookahead, s (default: control.plate.lookahead_for the liquid)")
    p.add_argument("--out", type=Path, default=None,
                   help="JSON results (default: bench/results/plate_misses_quick.json, _full.json with --full)")
    p.add_argument("--no-history", action="store_true", help="do not append to bench/history.jsonl")
    a = p.parse_args()
    try:
        targets = [int(t) for t in a.targets.split(",")]
        substeps = [int(s) for s in a.substeps.split(",")]
    except ValueError:
        raise SystemExit("--targets and --substeps take whole numbers separated by commas") from None
    if not all(0 <= t < 8 for t in targets) or not all(s >= 1 for s in substeps) or a.jobs < 1:
        raise SystemExit("targets are bowls 0-7, substeps and --jobs at least 1")
    if a.lookahead is not None and not (np.isfinite(a.lookahead) and a.lookahead >= 0):
        raise SystemExit(f"--lookahead takes seconds >= 0, got {a.lookahead}")
    out = a.out or (RESULTS.with_name("plate_misses_full.json") if a.full else RESULTS)
    work = [(t, substeps, not a.full, a.lookahead) for t in targets]
    if a.jobs == 1:
        results = [run_target(w) for w in work]
    else:
        with mp.get_context("spawn").Pool(a.jobs) as pool:
            results = pool.map(run_target, work)
    print(f"{'bowl':>4} {'caught':>7} {'splashed out':>13} {'missed':>7} {'entry speed p10/50/90, m/s':>28}   "
          f"replayed with dt/n, in target: " + " ".join(f"n={m}" for m in substeps))
    for r in results:
        e = r["entry_speed_m_s"]
        es = f"{e['p10']:.2f} / {e['median']:.2f} / {e['p90']:.2f}" if e else "—"
        rep = " ".join(f"{100 * r['replay_in_target'][str(m)]:5.1f}" for m in substeps)
        print(f"{r['target']:>4} {100 * r['caught']:6.1f}% {r['splashed_out']:>13} {r['missed']:>7} {es:>28}   {rep}")
        emit({"what": "plate_misses", "quick": not a.full, "lookahead_s": a.lookahead, **r}, not a.no_history)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"scene": "plate_tilt", "quick": not a.full, "seed": 0, "lookahead_s": a.lookahead,
                               "results": results}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
