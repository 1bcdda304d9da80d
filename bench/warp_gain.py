"""The warp-field tracker's gain and cap, swept on benchmark recordings.

    liquidtwin evaluate tracking --quick --trials 1 --seed 100 --trackers open_loop --data DIR
    python bench/warp_gain.py --data DIR --gains 600,50 --max-move 0.25,0.5 [--out sweep.json]

Replays every recording in ``DIR`` (as ``liquidtwin evaluate tracking`` does: IOU of the model
mask against the observed one before each correction) once per (gain, cap) pair, the pairs
taken in order (``--gains 600,50 --max-move 0.25,0.5``: gain 600 with cap 0.25 h, then 50
with 0.5 h; one cap for all gains when one is given). Prints per setting the pooled mean IOU
(the benchmark table's "overall" cell: frames with >= 50 observed px, pooled over pours), the
share of seen particles whose move hit the cap, and the pour-by-pour difference from the
first setting with a bootstrap 95 % interval (``tracking_paired.py``'s). The recordings are
the only input; their truth sidecars are not read.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.tracking_paired import paired  # noqa: E402

from liquidtwin.evaluate.replay import engine_for, replay  # noqa: E402
from liquidtwin.evaluate.tracking import series_mean  # noqa: E402
from liquidtwin.recordings import read_recording  # noqa: E402
from liquidtwin.tracking import WarpField  # noqa: E402

MIN_PX = 50


class _Counting(WarpField):
    """The warp field, counting how many seen particles' moves reach the cap."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.at_cap, self.seen = 0, 0

    def correct(self, obs):
        c = super().correct(obs)
        if c is not None:
            d = c.dx[obs.visible].norm(dim=1)
            self.at_cap += int((d >= 0.98 * self.max_move * obs.model.h).sum())
            self.seen += int(d.numel())
        return c


def sweep(data: Path, settings: list[tuple], *, frames: int | None = None, progress=print) -> list[dict]:
    """One run per (gain, cap[, agreeing share]): pooled IOU, share of moves at the cap, per-pour means."""
    paths = sorted(data.glob("*.mcap"))
    if not paths:
        raise SystemExit(f"no .mcap recordings in {data}")
    runs = []
    for setting in settings:
        gain, cap, agreeing = (*setting, 1.0)[:3]
        t0, cases, pooled, at_cap, seen = time.perf_counter(), [], [], 0, 0
        for path in paths:
            rec = read_recording(path)
            eng = engine_for(rec, "warp_field")
            eng._tracker = tracker = _Counting(gain, max_move=cap, agreeing_share=agreeing)    # swapped in
            r = replay(rec, eng, frames=frames)
            s = {"iou": r.iou, "observed_px": r.observed_px}
            pooled += [i for i, n in zip(r.iou, r.observed_px) if n >= MIN_PX]
            cases.append({"recording": path.name, "mean_iou": {"warp_field": series_mean(s, MIN_PX)}})
            at_cap, seen = at_cap + tracker.at_cap, seen + tracker.seen
        run = {"gain": gain, "max_move": cap, "agreeing_share": agreeing, "pooled_iou": float(np.mean(pooled)), "at_cap": at_cap / max(seen, 1),
               "wall_s": time.perf_counter() - t0, "cases": cases}
        progress(f"{_name(run)}: pooled IOU {run['pooled_iou']:.4f}, "
                 f"{100 * run['at_cap']:.0f} % of moves at the cap ({run['wall_s']:.0f} s)")
        runs.append(run)
    return runs


def _name(run: dict) -> str:
    share = run.get("agreeing_share", 1.0)
    return f"gain {run['gain']:g}, cap {run['max_move']:g} h" + ("" if share == 1.0 else f", agreeing x{share:g}")


def _print_paired(runs: list[dict]) -> None:
    base = runs[0]
    print(f"\npour by pour against {_name(base)} ({len(base['cases'])} pours; "
          "pours with no frame >= 50 px left out):")
    for run in runs[1:]:
        d = paired({"cases": base["cases"]}, {"cases": run["cases"]}, min_px=MIN_PX)
        w = next(x for x in d if x["column"] == "warp_field")
        print(f"  {_name(run)}: {w['mean_diff']:+.3f} "
              f"({w['low']:+.3f} to {w['high']:+.3f}), better on {w['b_better']}/{w['pours']}")


def _combine(paths: list[Path]) -> int:
    docs = [json.loads(p.read_text())["runs"] for p in paths]
    settings = [[(r["gain"], r["max_move"], r.get("agreeing_share", 1.0)) for r in d] for d in docs]
    if any(s != settings[0] for s in settings):
        raise SystemExit(f"the sweeps do not share their settings in order: {settings}")
    runs = [{**doc_runs[0], "cases": [{**c, "recording": f"{i}/{c['recording']}"}
                                      for i, d in enumerate(docs) for c in d[k]["cases"]]}
            for k, doc_runs in enumerate(zip(*docs))]
    _print_paired(runs)
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("--data", type=Path, default=None, help="recordings of `liquidtwin evaluate tracking --data DIR`")
    p.add_argument("--combine", type=Path, nargs="+", default=None, metavar="SWEEP.json",
                   help="instead of sweeping: pool the pours of earlier --out files (same settings in the same "
                        "order, e.g. one per base seed) and print each setting's paired difference from the first")
    p.add_argument("--gains", default="600,50", help="comma-separated gains (px at 640x480 per unit field)")
    p.add_argument("--max-move", default="0.5", help="comma-separated caps, kernel radii h (one for all, or one per gain)")
    p.add_argument("--agreeing", default="1", help="comma-separated shares of the pull given to particles already "
                   "drawn on observed liquid (WarpField(agreeing_share=...); one for all, or one per gain; default 1)")
    p.add_argument("--frames", type=int, default=None, help="only the first N pose samples of each recording")
    p.add_argument("--out", type=Path, default=None, help="write every run's per-pour means as JSON")
    args = p.parse_args(argv)
    if args.combine:
        return _combine(args.combine)
    if args.data is None:
        p.error("--data DIR is needed (or --combine SWEEP.json …)")
    gains = [float(g) for g in args.gains.split(",")]
    caps = [float(c) for c in args.max_move.split(",")]
    if len(caps) not in (1, len(gains)):
        raise SystemExit(f"--max-move takes one cap or one per gain ({len(gains)}), got {len(caps)}")
    shares = [float(a) for a in args.agreeing.split(",")]
    if len(shares) not in (1, len(gains)) or not all(0.0 <= a <= 1.0 for a in shares):
        raise SystemExit(f"--agreeing takes shares in [0, 1], once or once per gain ({len(gains)}), got {args.agreeing!r}")
    caps, shares = (v * len(gains) if len(v) == 1 else v for v in (caps, shares))
    runs = sweep(args.data, list(zip(gains, caps, shares)), frames=args.frames)
    _print_paired(runs)
    if args.out:
        args.out.write_text(json.dumps({"data": str(args.data), "runs": runs}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
