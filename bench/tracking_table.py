"""One Fig. 7.5 table from several ``liquidtwin evaluate tracking`` runs over the same recordings.

    python bench/tracking_table.py RUN.json [RUN.json …] [--min-px 50] [--first-target]

Runs that tracked other pours (the cups in one, the bottles in another: ``--cases 9`` and
``--cases 9:18``) or other trackers on the same pours (``--trackers open_loop
spnets_perception`` in one, ``--trackers map_filter warp_field`` in another) are merged pour by
pour: a pour's columns are the union of what the runs tracked, and a pour tracked by two runs
must have the same ceiling in both (else they are other recordings, and the script stops). The
rows pool frames as ``evaluate tracking``'s table does (``evaluate.tracking.table``).

``--first-target`` also prints, for every closed-loop column, the rows where it is not above
open loop (the issue's first target: every closed-loop column above open loop on every row),
to 0.01 IOU points.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from liquidtwin.evaluate.tracking import ROWS, format_table, table

ORDER = ("open_loop", "map_filter", "warp_field", "spnets_perception")


def merged(docs: list[dict]) -> tuple[list[dict], list[str]]:
    """(cases with every run's series of that pour, the columns in the table's order)."""
    by_name: dict = {}
    for doc in docs:
        for c in doc["cases"]:
            name = c["case"]["name"]
            if name not in by_name:
                by_name[name] = {**c, "series": dict(c["series"])}
                continue
            have = by_name[name]["series"]
            a, b = have.get("ceiling"), c["series"].get("ceiling")
            if a is not None and b is not None and (a["iou"] != b["iou"] or a["observed_px"] != b["observed_px"]):
                raise SystemExit(f"{name}: the runs' ceilings differ, so they tracked other recordings")
            for col, s in c["series"].items():
                have.setdefault(col, s)
    cols = {col for c in by_name.values() for col in c["series"]}
    columns = [c for c in ORDER if c in cols] + sorted(cols - set(ORDER) - {"ceiling"}) + ["ceiling"]
    return list(by_name.values()), columns


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path, help="results JSON of liquidtwin evaluate tracking runs")
    p.add_argument("--min-px", type=int, default=50, help="frames whose observed mask has fewer px are skipped (default 50)")
    p.add_argument("--first-target", action="store_true", help="list the rows where a closed-loop column is not above open loop")
    args = p.parse_args()
    cases, columns = merged([json.loads(r.read_text()) for r in args.runs])
    tab = table(cases, columns, args.min_px)
    print(format_table(tab, columns, args.min_px, f"{len(cases)} pours merged from {len(args.runs)} runs"))
    if args.first_target:
        if "open_loop" not in columns:
            raise SystemExit("no open-loop column to compare with")
        for col in columns:
            if col in ("open_loop", "ceiling"):
                continue
            below = [f"{row} ({100 * tab[row][col]:.2f} against {100 * tab[row]['open_loop']:.2f} %)" for row in ROWS
                     if tab[row][col] is not None and tab[row]["open_loop"] is not None
                     and not tab[row][col] > tab[row]["open_loop"]]
            print(f"{col}: " + ("above open loop on every row" if not below else "not above on " + ", ".join(below)))


if __name__ == "__main__":
    main()
