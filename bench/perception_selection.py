"""Training length chosen on held-out pours, against the last step: a table from the results
of ``liquidtwin evaluate perception --select-every N`` (its ``perception.json``).

Per network: the step the calibration pours chose and the test AUC there; the test AUC of
the last checkpoint (what training without selection returns, same seed and steps); the
best test AUC over all checkpoints and its step (an oracle that peeks at the test pours, for
the record: how much a perfect stand-in could gain); and the rank correlation of the
calibration and test curves over the checkpoints (how well pours of the training
containers stand in for new containers). ``--compare`` adds the test AUC of another results
file's same networks (e.g. the grid).

    python bench/perception_selection.py eval-sel/perception.json --compare bench/results/perception_grid.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _ranks(a) -> np.ndarray:
    a = np.asarray(a, float)
    r = np.empty(len(a))
    r[np.argsort(a, kind="stable")] = np.arange(len(a))
    return r


def spearman(a, b) -> float:
    """Rank correlation (ties broken by order; checkpoints rarely tie)."""
    ra, rb = _ranks(a), _ranks(b)
    return float(np.corrcoef(ra, rb)[0, 1]) if len(a) > 1 and ra.std() and rb.std() else float("nan")


def rows(doc: dict, compare: dict | None = None) -> list[dict]:
    other = {}
    if compare:
        other = {(r["kind"], r["input_type"], r["fusion"]): r["test"]["0"] for r in compare["results"]}
    out = []
    for r in doc["results"]:
        pts = r.get("checkpoints")
        if not pts:
            continue
        if "watch_auc" not in pts[0]:
            raise SystemExit("these results have no test curve (watch_auc); re-run evaluate perception")
        by_step = {p["step"]: p for p in pts}
        oracle = max(pts, key=lambda p: p["watch_auc"])
        key = (r["kind"], r["input_type"], r["fusion"])
        out.append({"network": "/".join(key), "chosen_step": r["selected_step"],
                    "calib_at_chosen": by_step[r["selected_step"]]["select_auc"],
                    "test_at_chosen": r["test"]["0"], "test_last": pts[-1]["watch_auc"], "last_step": pts[-1]["step"],
                    "test_oracle": oracle["watch_auc"], "oracle_step": oracle["step"],
                    "spearman": spearman([p["select_auc"] for p in pts], [p["watch_auc"] for p in pts]),
                    "compare": other.get(key)})
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("results", type=Path, help="perception.json of an `evaluate perception --select-every` run")
    p.add_argument("--compare", type=Path, default=None, help="another perception.json (e.g. the grid)")
    args = p.parse_args(argv)
    doc = json.loads(args.results.read_text())
    table = rows(doc, json.loads(args.compare.read_text()) if args.compare else None)
    if not table:
        raise SystemExit(f"{args.results} has no checkpoints: run evaluate perception with --select-every N")
    base = doc["baseline"]["test"]["0"]
    print(f"test AUC % (0 px, unseen containers); baseline {100 * base:.1f} %")
    head = f"{'network':<26}{'compare':>8}{'last':>7}{'chosen':>8}{'step':>6}{'calib':>7}{'oracle':>8}{'step':>6}{'rho':>6}"
    print(head)
    for t in table:
        cmp = "–" if t["compare"] is None else f"{100 * t['compare']:.1f}"
        print(f"{t['network']:<26}{cmp:>8}{100 * t['test_last']:>7.1f}{100 * t['test_at_chosen']:>8.1f}"
              f"{t['chosen_step']:>6}{100 * t['calib_at_chosen']:>7.1f}{100 * t['test_oracle']:>8.1f}"
              f"{t['oracle_step']:>6}{t['spearman']:>6.2f}")
    gain = np.array([t["test_at_chosen"] - t["test_last"] for t in table])
    print(f"chosen − last: mean {100 * gain.mean():+.1f} points, better on {int((gain > 0).sum())}/{len(gain)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
