"""Run tests (or any pytest selection) with the SPNets neighbour skin set to S·h: the same
physics, other float rounding, so another realisation of every chaotic rollout.

    OMP_NUM_THREADS=1 .venv/bin/python bench/perturbed.py S [pytest arguments ...]
    # e.g. the MAP/warp/SPNets margins over three generated pours at four roundings:
    for s in 0 0.05 0.1 0.2; do
        .venv/bin/python bench/perturbed.py $s -q -s tests/server/test_tracking_spnets.py -k generated_pours
    done

A step's result does not depend on the skin beyond rounding (one float64 step of the
``liquidtwin bench`` basin: positions equal to 1e-16 m for skins 0, 0.1 h and 0.3 h), but the
particles are sorted and summed in another order, and a rollout of a splashing liquid
amplifies that difference within a second. A test whose assertion holds at one skin and fails
at another is asserting on one realisation of chaos; this is how the margins of such tests
are checked (the skin default changed from 0.1 h to 0 at stop 47). It sets
``liquidtwin.sim.pbf.DEFAULT_SKIN`` in this process only: models made with an explicit skin,
and servers that tests start as subprocesses, keep theirs.
"""

from __future__ import annotations

import sys

import pytest

from liquidtwin.sim import pbf


def main() -> int:
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        print(__doc__)
        return 0 if len(sys.argv) >= 2 else 2
    try:
        scale = float(sys.argv[1])
    except ValueError:
        raise SystemExit(f"the first argument is the skin in units of h (a number >= 0), got {sys.argv[1]!r}")
    if not scale >= 0:
        raise SystemExit(f"the skin must be >= 0, got {scale}")
    pbf.DEFAULT_SKIN = scale   # models created from here on, in this process
    print(f"neighbour skin {scale} h in this process", flush=True)
    return pytest.main(sys.argv[2:])


if __name__ == "__main__":
    sys.exit(main())
