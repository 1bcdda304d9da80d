"""bench/tracker_cost.py fills its basin to the particle count asked for (the issue's 4k and 8k
figures): ``fill_ml`` rescales the volume by the count each fill gives until it is within 3 %."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.tracker_cost import ML_PER_PARTICLE, _spec, fill_ml  # noqa: E402
from liquidtwin_proto import liquidtwin_pb2 as pb  # noqa: E402

from liquidtwin.session import SessionEngine  # noqa: E402


def test_the_fill_reaches_the_asked_count():
    n = 1500
    ml = fill_ml(n)
    got = SessionEngine.create(_spec(n, pb.OPEN_LOOP, ml)).n_particles
    assert abs(got - n) <= 0.03 * n, (got, n, ml, n * ML_PER_PARTICLE)
