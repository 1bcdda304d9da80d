"""How well the discrepancy analysis's calibration recovers the world's fluid parameters:
the calibrated λ_v, λ_c of each analysis in saved blind-benchmark results, against the
world's values from the recordings' truth sidecars (scoring only: the analysis never reads
them). The recordings state liquidtwin's defaults (``--stated``); the world jitters them by ±5–15 %,
and a planted ``viscosity`` or ``cohesion`` moves one further.

    .venv/bin/python bench/discrepancy_calibration.py RESULTS.json … --data DIR [DIR …]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", nargs="+", type=Path, help="results.json files of `liquidtwin evaluate discrepancy`")
    p.add_argument("--data", nargs="+", type=Path, required=True, help="directories holding the recordings' truth sidecars")
    p.add_argument("--stated", default="lambda_v=60,lambda_c=0.1", metavar="P=V,P=V",
                   help="the values the recordings state (default: the model's defaults, which the generated "
                        "benchmark recordings state)")
    args = p.parse_args()
    stated = {k: float(v) for k, v in (kv.split("=") for kv in args.stated.split(","))}
    seen, pairs = set(), {k: [] for k in stated}
    print(f"{'recording':<44}{'planted':<14}" + "".join(f"{'world ' + k:>16}{'calibrated':>12}" for k in stated))
    for path in args.results:
        for row in json.loads(path.read_text())["rows"]:
            name = row["case"]["name"]
            truth = next((d / f"{name}.truth.json" for d in args.data if (d / f"{name}.truth.json").exists()), None)
            if name in seen or truth is None:
                continue
            seen.add(name)
            world = json.loads(truth.read_text())["world"]["params"]
            cal = row["baseline"]["params"]
            cal = cal if isinstance(cal, dict) else {}
            line = f"{name:<44}{row['planted']:<14}"
            for k in stated:
                c = float(cal.get(k, stated[k]))
                line += f"{world[k]:>16.3g}{c:>12.3g}"
                if row["planted"] not in ("viscosity", "cohesion"):
                    pairs[k].append((world[k] / stated[k], c / stated[k]))
            print(line)
    for k, v in pairs.items():
        w, c = np.array(v).T
        r = float(np.corrcoef(w, c)[0, 1]) if len(v) > 2 and w.std() > 0 and c.std() > 0 else float("nan")
        print(f"\n{k} (stated {stated[k]:g}), {len(v)} recordings without a planted fluid change: world/stated "
              f"{w.min():.2f}–{w.max():.2f}, calibrated/stated {c.min():.2f}–{c.max():.2f}; correlation {r:+.2f}; "
              f"median |calibrated − world| / world {np.median(np.abs(c - w) / w):.0%} "
              f"(the stated value's: {np.median(np.abs(1 - w) / w):.0%})")


if __name__ == "__main__":
    main()
