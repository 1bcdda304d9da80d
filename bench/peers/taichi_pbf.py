"""Taichi peer: a standard 3-D Position Based Fluids dam break on the CPU backend.

    python -m bench.peers.taichi_pbf --particles 8000            # one JSON line
    python -m bench.peers.taichi_pbf --particles 2000 8000 32000  # one line each
    python -m bench.peers.taichi_pbf --validate --particles 4000  # physics check

Needs the bench-only extra (``pip install -r bench/requirements-peers.txt``).
Without it :func:`run` raises :class:`bench.peers.PeerNotInstalled` and the
script exits with status 2 and a one-line message on stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import sys

from bench.peers import PeerNotInstalled

PEER = "taichi"
PACKAGE = "taichi"
DEFAULT_THREADS = 2  # the project machines have 2 cores; the bench compares like with like


def _impl():
    """Import the Taichi implementation, or raise PeerNotInstalled."""
    try:
        with contextlib.redirect_stdout(sys.stderr):  # taichi prints a banner on first import
            import taichi  # noqa: F401  (sys.modules['taichi'] = None also lands here)
    except ImportError as exc:
        raise PeerNotInstalled(PEER, PACKAGE, exc) from exc
    return importlib.import_module("bench.peers._taichi_impl")


def available() -> bool:
    try:
        _impl()
    except PeerNotInstalled:
        return False
    return True


def version() -> str:
    return _impl().TAICHI_VERSION


def run(n_particles: int, steps: int = 50, warmup: int = 10,
        threads: int = DEFAULT_THREADS) -> dict:
    """Time ``steps`` PBF steps (3 solver iterations each) of an N-particle dam break.

    The ``warmup`` steps before them (at least one, which JIT-compiles the
    kernels) are not timed; the clock is read after ``ti.sync()``.  Returns
    ``{"peer", "version", "particles", "steps", "particle_steps_per_s",
    "mean_neighbors", "iterations", ...}``; raises PeerNotInstalled when
    taichi is missing.
    """
    return _impl().timed_run(int(n_particles), int(steps), int(warmup), threads=int(threads))


def validate(n_particles: int = 4000, steps: int = 600, threads: int = DEFAULT_THREADS) -> dict:
    """Run the dam break to rest and return sanity numbers (density, neighbours, box)."""
    return _impl().validate(int(n_particles), int(steps), threads=int(threads))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.peers.taichi_pbf",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, nargs="+", default=[8000])
    ap.add_argument("--steps", type=int, default=None, help="timed steps (default 50)")
    ap.add_argument("--warmup", type=int, default=10)
    ap.add_argument("--threads", type=int, default=DEFAULT_THREADS)
    ap.add_argument("--validate", action="store_true",
                    help="run a dam break to rest (--steps defaults to 600) "
                         "and print physics checks")
    args = ap.parse_args(argv)
    try:
        for n in args.particles:
            if args.validate:
                steps = 600 if args.steps is None else args.steps
                out = validate(n, steps, threads=args.threads)
            else:
                steps = 50 if args.steps is None else args.steps
                out = run(n, steps=steps, warmup=args.warmup, threads=args.threads)
            print(json.dumps(out), flush=True)
    except PeerNotInstalled as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
