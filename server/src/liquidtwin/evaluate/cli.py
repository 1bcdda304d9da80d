"""``liquidtwin evaluate KIND``: the thesis-style evaluations on generated benchmarks.

Each kind lives in its own module of this package exposing ``HELP`` (one line),
``configure(parser)`` and ``run(args) -> exit code``; add it to :data:`KINDS`. Every kind
prints a table, writes JSON (with the seeds) and PNG figures into ``--out``.
"""

from __future__ import annotations

import argparse
import importlib

#: evaluate kind → module (relative to this package).
KINDS = {"tracking": ".tracking", "fill": ".fill", "blockage": ".blockage", "volume": ".volume"}

HELP = "thesis-style evaluations on generated benchmarks: " + ", ".join(KINDS)


def _module(kind: str):
    return importlib.import_module(KINDS[kind], __package__)


def configure(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="kind", metavar="KIND", required=True)
    for kind in KINDS:
        try:
            mod = _module(kind)
        except ModuleNotFoundError:         # a kind still being written: keep the others usable
            continue
        sp = sub.add_parser(kind, help=mod.HELP, description=mod.HELP)
        mod.configure(sp)


def run(args: argparse.Namespace) -> int:
    return int(_module(args.kind).run(args) or 0)


def add_common(p: argparse.ArgumentParser, *, out: str) -> None:
    """Options every kind shares: data cache, output folder, quick variant, seeds, jobs."""
    from pathlib import Path
    p.add_argument("--data", type=Path, default=Path("eval-data"), metavar="DIR",
                   help="where benchmark recordings are cached (generated when missing; default: %(default)s)")
    p.add_argument("--out", type=Path, default=Path(out), metavar="DIR",
                   help="where the JSON and PNG results go (default: %(default)s)")
    p.add_argument("--quick", action="store_true",
                   help="quick scenes (20 %% of the liquid, 320x240, sped up): minutes instead of hours")
    p.add_argument("--trials", type=int, default=2, metavar="N", help="trials per case (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="base seed of the cases (default: %(default)s)")
    p.add_argument("--jobs", type=int, default=2, metavar="N",
                   help="processes generating recordings (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")
