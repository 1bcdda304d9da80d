"""Where the liquid went, pour by pour: the liquid budget of ``liquidtwin evaluate volume`` runs.

    python bench/volume_budget.py A/results.json [B/results.json …] [--tracker open_loop]

For every pour and every run, from the volume series the evaluation stored (truth: the world's
held particles; each run: the named tracker's particle count), in ml:

- ``held``: source + target at the first and the last mask frame;
- ``poured``: what left the source (first − last source volume);
- ``landed``: what the target gained (last − first target volume);
- ``lost``: poured − landed, liquid that left the source and is in neither container at the
  end (splashed out of the target, sprayed from the lip, or still in the air).

With ``--speeds`` it also reads each pour's truth (``REC.truth.npz`` beside the recording the
first run names) and prints how fast the world's particles moved near the scene (within
``NEAR_M`` of the origin horizontally, above the floor): the largest speed between pose
samples and how many particles ever exceeded ``FAST_M_S`` (liquid falling 35 cm lands at
2.6 m/s; faster is a splash or a burst of the solver).

It answers whether a run's target reads other than the truth because its model pours another
amount (``poured``) or because another share of what it pours misses or leaves the target
(``lost``). The first run's truth is printed once (every run must be over the same recordings).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


NEAR_M = 1.0
FAST_M_S = 5.0


def world_speeds(recording: Path) -> tuple[float, int, int]:
    """(largest speed m/s, particles ever faster than FAST_M_S, particles) of a generated
    recording's true particles near the scene (the truth sidecar; scoring only)."""
    z = np.load(Path(recording).with_suffix(".truth.npz"), allow_pickle=False)
    x = z["particles"].astype(np.float64)
    t = z["pose_stamps_ns"].astype(np.float64) * 1e-9
    v = np.linalg.norm(np.diff(x, axis=0), axis=-1) / np.diff(t)[:, None]
    near = (x[:-1, :, 1] > -0.02) & (np.abs(x[:-1][..., [0, 2]]).max(-1) < NEAR_M)
    v = np.where(near, v, 0.0)
    return float(v.max()), int((v > FAST_M_S).any(0).sum()), x.shape[1]


def budget(series: dict) -> dict:
    """{held_start, held_end, poured, landed, lost} ml of one {source, target} volume series."""
    src, tgt = (np.asarray(series[k], float) for k in ("source", "target"))
    poured, landed = src[0] - src[-1], tgt[-1] - tgt[0]
    return {"held_start": src[0] + tgt[0], "held_end": src[-1] + tgt[-1], "poured": poured,
            "landed": landed, "lost": poured - landed}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", nargs="+", type=Path, help="results.json of liquidtwin evaluate volume runs")
    p.add_argument("--tracker", default=None, help="whose particle count (default: the first each run scored)")
    p.add_argument("--speeds", action="store_true", help="also the world's particle speeds (reads the truth sidecars)")
    args = p.parse_args()
    runs = [json.loads(r.read_text()) for r in args.results]
    names = [c["case"]["name"] for c in runs[0]["cases"]]
    for r, path in zip(runs[1:], args.results[1:]):
        if [c["case"]["name"] for c in r["cases"]] != names:
            raise SystemExit(f"{path} is over other pours than {args.results[0]}: compare runs over the same cases")
    # a run's label: its --out folder for a results.json, else the file's name
    heads = ["truth"] + [f"{i + 1}: {r.parent.name if r.name == 'results.json' else r.stem}"
                         for i, r in enumerate(args.results)]
    print("ml: held at the start -> end | poured from the source | landed in the target | lost (poured - landed)")
    print("pour".ljust(28) + "".join(h[:34].ljust(36) for h in heads)
          + (f"world: max m/s, particles > {FAST_M_S:g} m/s" if args.speeds else ""))
    totals = [np.zeros(3) for _ in heads]
    for i, name in enumerate(names):
        cells = []
        for k, (h, r) in enumerate(zip(heads, [runs[0]] + runs)):
            case = r["cases"][i]
            if k == 0:
                s = case["truth"]
            else:
                trackers = case["particles"]
                t = args.tracker or next(iter(trackers))
                if t not in trackers:
                    raise SystemExit(f"{h}: no particle count of {t} (has {', '.join(trackers)})")
                s = trackers[t]
            b = budget(s)
            totals[k] += [b["poured"], b["landed"], b["lost"]]
            cells.append(f"{b['held_start']:4.0f}->{b['held_end']:4.0f} | {b['poured']:4.0f} | "
                         f"{b['landed']:4.0f} | {b['lost']:4.0f}")
        speeds = ""
        if args.speeds:
            vmax, fast, n = world_speeds(Path(runs[0]["cases"][i]["recording"]))
            speeds = f"{vmax:5.1f} | {fast} of {n}"
        print(name[:27].ljust(28) + "".join(c.ljust(36) for c in cells) + speeds)
    print("all pours".ljust(28) + "".join(f"poured {t[0]:5.0f}, lost {t[2]:4.0f} ({t[2] / max(t[0], 1e-9):.0%})".ljust(36)
                                          for t in totals))


if __name__ == "__main__":
    main()
