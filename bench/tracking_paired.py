"""Two tracking runs compared pour by pour: is the difference more than the spread of a
chaotic rollout?

    python bench/tracking_paired.py A/tracking.json B/tracking.json

Both files come from ``liquidtwin evaluate tracking`` over the same recordings (e.g. the
same pours tracked with two detectors, ``--detector``). For every column both runs have
(``map_filter/detected``, ``warp_field`` …), and for the detector's own mask IOU when both
used one, it pairs the pours by case (their ceilings must agree), takes each pour's mean IOU (B − A) and prints the
mean difference with a bootstrap 95 % interval over pours and how many pours B wins. The
table of ``evaluate tracking`` pools frames instead, so its overall row weighs long pours more.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from liquidtwin.evaluate.tracking import series_mean

MIN_PX = 50


def _key(case: dict) -> str:
    """A pour's identity: its benchmark case name (the recording's file name without suffix),
    so runs over two --data directories of the same cases pair up."""
    return case["case"]["name"] if "case" in case else Path(case["recording"]).stem


def paired(a: dict, b: dict, *, min_px: int = MIN_PX, resamples: int = 5000, seed: int = 0) -> list[dict]:
    """Per column: n pours, mean B − A, 95 % bootstrap interval, pours where B > A."""
    ca, cb = ({_key(c): c for c in doc["cases"]} for doc in (a, b))
    common = [k for k in ca if k in cb]
    if not common:
        raise SystemExit("the two runs share no recording: compare runs over the same cases")
    for k in common:            # the same case name in two --data dirs must be the same recording
        x, y = ca[k]["mean_iou"].get("ceiling"), cb[k]["mean_iou"].get("ceiling")
        if x is not None and y is not None and abs(x - y) > 1e-9:
            raise SystemExit(f"{k}: the runs' ceilings differ ({x:.6f}, {y:.6f}): not the same recording")
    columns = [c for c in ca[common[0]]["mean_iou"] if c != "ceiling" and c in cb[common[0]]["mean_iou"]]
    values = {c: [(ca[k]["mean_iou"].get(c), cb[k]["mean_iou"].get(c)) for k in common] for c in columns}
    values["detector mask"] = [(series_mean(ca[k].get("detector"), min_px), series_mean(cb[k].get("detector"), min_px))
                              for k in common]
    rng = np.random.default_rng(seed)
    out = []
    for col, pairs in values.items():
        d = np.array([y - x for x, y in pairs if x is not None and y is not None])
        if not len(d):
            continue
        boots = d[rng.integers(len(d), size=(resamples, len(d)))].mean(axis=1)
        lo, hi = np.percentile(boots, [2.5, 97.5])
        out.append({"column": col, "pours": int(len(d)), "mean_diff": float(d.mean()), "low": float(lo),
                    "high": float(hi), "b_better": int((d > 0).sum())})
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("a", type=Path, help="tracking.json of run A")
    p.add_argument("b", type=Path, help="tracking.json of run B (differences are B − A)")
    p.add_argument("--min-px", type=int, default=MIN_PX, help="frames scored for the detector mask (default: %(default)s)")
    args = p.parse_args(argv)
    rows = paired(json.loads(args.a.read_text()), json.loads(args.b.read_text()), min_px=args.min_px)
    print(f"{'column':<24}{'pours':>6}{'B − A':>9}{'95 % interval':>20}{'B better':>10}")
    for r in rows:
        interval = f"{100 * r['low']:+.2f} to {100 * r['high']:+.2f}"
        print(f"{r['column']:<24}{r['pours']:>6}{100 * r['mean_diff']:>+9.2f}{interval:>20}{r['b_better']:>10}")
    print("IOU points; mean of per-pour mean IOU differences, bootstrap over pours")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
