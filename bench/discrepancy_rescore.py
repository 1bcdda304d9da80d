"""Re-score saved blind-benchmark results (``liquidtwin evaluate discrepancy``'s results.json)
with the current scoring, without re-running any analysis: the ``tied`` range of each named
candidate is recomputed from its saved trace, so results from before the range existed are
scored as a fresh run would be.

    .venv/bin/python bench/discrepancy_rescore.py bench/results/discrepancy_quick_seed0.json [more.json …]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", nargs="+", type=Path, help="results.json files of the blind benchmark")
    args = p.parse_args()
    from liquidtwin.discrepancy.candidates import tied_range
    from liquidtwin.evaluate.discrepancy import format_table, identified, table

    for path in args.results:
        doc = json.loads(path.read_text())
        rows = doc["rows"]
        for row in rows:
            for c in row["candidates"]:
                if "tied" not in c and c.get("trace"):
                    c["tied"] = tied_range(c["name"], [(t["params"], t["fit_loss"]) for t in c["trace"]])
            if row["correct"] and row["planted"] != "none":
                row["identified"] = identified(next(c for c in row["candidates"] if c["name"] == row["named"]))
        note = f"{path}: re-scored ({len(rows)} analyses, base seed {doc.get('base_seed')})"
        print(format_table(table(rows), note), "\n")


if __name__ == "__main__":
    main()
