"""The volume filter's transition, learned from generated pours (SPEC §5: "transition learned
from data"), and the shipped result.

``python -m liquidtwin.volumes.learn [--data DIR] [--out FILE] [--trials N] [--seed N]`` generates
(or reuses) quick pouring recordings of :mod:`liquidtwin.evaluate.benchmark` with seeds apart
from the evaluation's (default base seed 50000; the evaluation uses 0), reads every
container's true volume per mask frame from the truth sidecars (training data, not analysis),
and counts bin changes with :func:`~liquidtwin.volumes.hmm.learn_transition`.

Volumes are learned as **fractions of all the liquid in the scene** (u = v / V_total, bins
:data:`~liquidtwin.volumes.transition.U_BINS`): a session knows its total (the fills it was
given), and the per-frame changes of a pour then look alike whatever the amount.
:func:`~liquidtwin.volumes.transition.scaled_transition` turns the shipped matrix into one over
a session's bins in ml. The file is a plain ``.npz`` (no pickle):
``u_bins`` (K,), ``transition`` (K, K), ``seeds`` (cases used), ``frames`` (transitions counted),
``prior`` and ``pooled`` (the pseudo-counts of :func:`~liquidtwin.volumes.hmm.learn_transition`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from .expected import quat_matrix
from .hmm import learn_transition
from .transition import SHIPPED, U_BINS

def true_fractions(path: Path) -> list[np.ndarray]:
    """Per container, (M,) the fraction of the scene's true particles inside its cavity at each
    mask frame of the recording ``path`` (reads the truth sidecar: training / scoring only)."""
    from ..recordings import read_recording
    from ..scenes.spec import scene_objects
    rec = read_recording(path, images=False)
    items = scene_objects(rec.spec, base_dir=Path(path).parent)
    stamps = rec.masks[next(iter(rec.masks))][0]
    z = np.load(Path(path).with_suffix(".truth.npz"), allow_pickle=False)
    ks = np.minimum(np.searchsorted(z["pose_stamps_ns"], stamps), len(z["pose_stamps_ns"]) - 1)
    out = []
    for i, (_, obj, _) in enumerate(items):
        if obj.cavity is None:
            continue
        fr = []
        for k in ks:
            pose = z["true_poses"][k][i]
            local = (z["particles"][k] - pose[:3]) @ quat_matrix(pose[3:])
            fr.append(obj.in_cavity(local).sum() / max(1, len(local)))
        out.append(np.array(fr, float))
    return out


def main(argv=None) -> int:
    from ..evaluate.benchmark import cases, ensure
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("eval-data"), help="recording cache (default: %(default)s)")
    ap.add_argument("--out", type=Path, default=SHIPPED, help="where the .npz goes (default: the shipped file)")
    ap.add_argument("--trials", type=int, default=1, help="trials per benchmark case (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=50000, help="base seed, apart from the evaluation's (default: %(default)s)")
    ap.add_argument("--jobs", type=int, default=2, help="generating processes (default: %(default)s)")
    ap.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    ap.add_argument("--prior", type=float, default=0.01, help="pseudo-count per entry (default: %(default)s)")
    ap.add_argument("--pooled", type=float, default=20.0,
                    help="pseudo-counts per row shaped like all rows' bin changes (default: %(default)s)")
    a = ap.parse_args(argv)
    cs = cases(quick=True, trials=a.trials, base_seed=a.seed)
    paths = ensure(cs, a.data, jobs=a.jobs, progress=not a.no_progress)
    series = [s for p in paths for s in true_fractions(p)]
    T = learn_transition(series, U_BINS, prior=a.prior, pooled=a.pooled)
    frames = int(sum(len(s) - 1 for s in series))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(a.out, u_bins=U_BINS, transition=T, seeds=np.array([c.seed for c in cs]), frames=frames,
             prior=a.prior, pooled=a.pooled)
    stay = float(np.mean(np.diag(T)[:10]))
    print(json.dumps({"out": str(a.out), "cases": len(cs), "series": len(series), "transitions": frames,
                      "mean_stay_probability_low_bins": round(stay, 4)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
