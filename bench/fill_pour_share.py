"""Does the model pour what the benchmark's world pours? At the end of each pouring-benchmark
recording, the share of the liquid that has left the source, and the share that is in
neither the source nor the target (spilled: splashed out, missed the bowl, or fell off): in
the world (the truth sidecar; scoring only) and in liquidtwin's open-loop model started from
the recording's stated fill.

    OMP_NUM_THREADS=1 .venv/bin/python bench/fill_pour_share.py --seed 100 --kinds partial hold \
        --data eval-data [--full] [--no-effects] [--no-history]

Why: fill inference (``liquidtwin evaluate fill``) compares what each fill hypothesis pours
with what the camera sees. When the world's jittered parameters and mild hidden effect keep
a fill from pouring that the model pours (or the reverse), no likelihood can rank the true
fill first from an open-loop simulation. Recordings are generated into ``--data`` when
missing (the same cache and names as ``liquidtwin evaluate``). Prints one row per case and
appends one record per case to bench/history.jsonl.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from _record import emit
from liquidtwin.evaluate import engine_for
from liquidtwin.evaluate.benchmark import FILLS, KINDS, SOURCES, cases, ensure
from liquidtwin.evaluate.replay import replay
from liquidtwin.recordings import read_recording
from liquidtwin.scenes.liquid_level import held
from liquidtwin.sim import FluidState


def held_share(model, x: np.ndarray, poses: np.ndarray, k: int, obj) -> float:
    """Share of the particles x (N, 3) that container k (pose poses[k]) holds."""
    if len(x) == 0:
        return 0.0
    s = FluidState(torch.as_tensor(x, dtype=torch.float64), torch.zeros(len(x), 3, dtype=torch.float64),
                   torch.arange(len(x)), torch.as_tensor(poses, dtype=torch.float64), 0.0)
    return float(held(model, s, k, obj)[0].mean())


def measure(path: Path) -> dict:
    rec = read_recording(path, images=False)
    eng = engine_for(rec, "open_loop")
    scene = eng._scene                                  # read only: its objects decide "held"
    model = scene.model
    k, dst = eng.object_names.index("source"), eng.object_names.index("target")
    replay(rec, eng)
    poses = np.asarray(eng._frame_poses, float)
    n0 = eng.n_particles + eng.lost_particles
    truth = np.load(path.with_suffix(".truth.npz"))
    out = {"model_particles": n0, "world_particles": int(truth["particles"].shape[1])}
    for who, x, P, n in (("model", eng.positions(), poses, n0),
                         ("world", truth["particles"][-1], truth["true_poses"][-1], truth["particles"].shape[1])):
        # culled particles (fell below every object) left the source and missed the target
        in_src, in_dst = (len(x) / max(n, 1) * held_share(model, x, P, j, scene.objects[j]) for j in (k, dst))
        out[f"{who}_left"], out[f"{who}_spilled"] = 1.0 - in_src, 1.0 - in_src - in_dst
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=100, help="benchmark base seed (default: %(default)s)")
    p.add_argument("--kinds", nargs="+", default=["partial"], choices=KINDS)
    p.add_argument("--sources", nargs="+", default=list(SOURCES), choices=SOURCES)
    p.add_argument("--data", type=Path, default=Path("eval-data"), help="recording cache (default: %(default)s)")
    p.add_argument("--jobs", type=int, default=1, help="processes generating missing recordings")
    p.add_argument("--full", action="store_true", help="the full scenes (default: quick)")
    p.add_argument("--no-effects", action="store_true",
                   help="the same worlds without their hidden effect (same seeds, so the same jitter and noise; "
                        "use another --data: the recordings keep their names)")
    p.add_argument("--no-history", action="store_true")
    a = p.parse_args()
    torch.set_num_threads(1)
    case_list = cases(quick=not a.full, trials=1, sources=tuple(a.sources), fills=(0.0,) + FILLS, kinds=tuple(a.kinds),
                      base_seed=a.seed, effects=not a.no_effects)
    paths = ensure(case_list, a.data, jobs=a.jobs)
    print(f"{'case':28s} {'hidden effect':24s} {'poured: world':>13s} {'model':>6s} {'spilled: world':>15s} {'model':>6s}")
    for case, path in zip(case_list, paths):
        if case.fraction == 0:                          # the fill benchmark's empty cases: nothing to pour
            continue
        r = measure(Path(path))
        hidden = f"{case.effect} {case.effect_value:.3g}" if case.effect else "none"
        print(f"{case.name:28s} {hidden:24s} {100 * r['world_left']:12.0f}% "
              f"{100 * r['model_left']:5.0f}% {100 * r['world_spilled']:14.0f}% {100 * r['model_spilled']:5.0f}%",
              flush=True)
        emit({"what": "fill_pour_share", "case": case.name, "effect": case.effect, "effect_value": case.effect_value,
              **r}, not a.no_history)


if __name__ == "__main__":
    main()
