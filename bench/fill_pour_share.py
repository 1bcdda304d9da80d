"""Does the model pour what the benchmark's world pours? The share of the source's liquid that
has left it at the end of each pouring-benchmark recording: in the world (the truth sidecar;
scoring only) and in liquidtwin's open-loop model started from the recording's stated fill.

    OMP_NUM_THREADS=1 .venv/bin/python bench/fill_pour_share.py --seed 100 --kinds partial hold \
        --data eval-data [--no-history]

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


def left_share(model, x: np.ndarray, poses: np.ndarray, k: int, obj) -> float:
    """Share of the particles x (N, 3) that container k (pose poses[k]) does not hold."""
    if len(x) == 0:
        return 0.0
    s = FluidState(torch.as_tensor(x, dtype=torch.float64), torch.zeros(len(x), 3, dtype=torch.float64),
                   torch.arange(len(x)), torch.as_tensor(poses, dtype=torch.float64), 0.0)
    return 1.0 - float(held(model, s, k, obj)[0].mean())


def measure(path: Path) -> dict:
    rec = read_recording(path, images=False)
    eng = engine_for(rec, "open_loop")
    scene = eng._scene                                  # read only: its objects decide "held"
    name = eng.container_names[0] if "source" not in eng.container_names else "source"
    k = eng.object_names.index(name)
    model = scene.model
    replay(rec, eng)
    poses = np.asarray(eng._frame_poses, float)
    model_left = left_share(model, eng.positions(), poses, k, scene.objects[k]) if eng.n_particles else 0.0
    n0 = eng.n_particles + eng.lost_particles
    model_left = 1.0 - (1.0 - model_left) * eng.n_particles / max(n0, 1)      # culled ones left too
    truth = np.load(path.with_suffix(".truth.npz"))
    world_left = left_share(model, truth["particles"][-1], truth["true_poses"][-1], k, scene.objects[k])
    return {"world_left": world_left, "model_left": model_left, "model_particles": n0,
            "world_particles": int(truth["particles"].shape[1])}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=100, help="benchmark base seed (default: %(default)s)")
    p.add_argument("--kinds", nargs="+", default=["partial"], choices=KINDS)
    p.add_argument("--sources", nargs="+", default=list(SOURCES), choices=SOURCES)
    p.add_argument("--data", type=Path, default=Path("eval-data"), help="recording cache (default: %(default)s)")
    p.add_argument("--jobs", type=int, default=1, help="processes generating missing recordings")
    p.add_argument("--no-history", action="store_true")
    a = p.parse_args()
    torch.set_num_threads(1)
    case_list = cases(quick=True, trials=1, sources=tuple(a.sources), fills=(0.0,) + FILLS, kinds=tuple(a.kinds),
                      base_seed=a.seed)
    paths = ensure(case_list, a.data, jobs=a.jobs)
    print(f"{'case':28s} {'hidden effect':24s} {'world poured':>12s} {'model poured':>12s}")
    for case, path in zip(case_list, paths):
        if case.fraction == 0:                          # the fill benchmark's empty cases: nothing to pour
            continue
        r = measure(Path(path))
        print(f"{case.name:28s} {f'{case.effect} {case.effect_value:.3g}':24s} {100 * r['world_left']:11.0f}% "
              f"{100 * r['model_left']:11.0f}%", flush=True)
        emit({"what": "fill_pour_share", "case": case.name, "effect": case.effect, "effect_value": case.effect_value,
              **r}, not a.no_history)


if __name__ == "__main__":
    main()
