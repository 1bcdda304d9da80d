"""bench/tracker_cost.py fills its basin to the particle count asked for (the issue's 4k and 8k
figures): ``fill_ml`` searches the volume (rescaling, then interpolating) until the count is within 3 %."""

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


def test_each_asked_tracker_is_timed_after_open_loop_on_the_same_fill():
    from bench.tracker_cost import run
    recs = run(400, 3, ("spnets_perception",))
    assert [r["mode"] for r in recs] == ["OPEN_LOOP", "SPNETS_PERCEPTION"]
    assert recs[0]["frame_ratio"] == 1.0 and recs[0]["particles"] == recs[1]["particles"]
    assert all(r["ms"] > 0 and r["step_ms"] > 0 for r in recs)
    assert recs[1]["frame_ratio"] == round(recs[1]["ms"] / recs[0]["ms"], 3)
