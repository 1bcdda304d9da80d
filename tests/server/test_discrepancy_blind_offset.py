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


def _check(path, candidates, report):
    truth = _truth(path)
    assert report["decision"] == truth["name"], (report["decision"], truth,
                                                 [(c["name"], c["heldout_gain"], c.get("null_gains"))
                                                  for c in report["candidates"]])
    c = _candidate(report, truth["name"])
    assert c["heldout_gain"]["ci95"][0] > 0
    assert report["extended"]["heldout_loss"] < report["baseline"]["heldout_loss"]
    return truth, c


def test_time_offset_is_told_from_camera_offset(recordings):
    path = recordings["time_offset"]
    report = analyse([path], options=Options(candidates=("time_offset", "camera_offset"), top=2))
    truth, c = _check(path, ("time_offset", "camera_offset"), report)
    assert abs(c["value"] - truth["value"]) <= 0.25 * abs(truth["value"])
