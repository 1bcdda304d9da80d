"""Discrepancy discovery in worker processes (``Options.jobs``) gives the serial report: the
workers run the same searches, the analysis replays them from their evaluations."""

import pytest
import torch
from blind_cases import record

from liquidtwin.discrepancy import Options, analyse
from liquidtwin.discrepancy import analysis

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


def _comparable(report: dict) -> dict:
    """The report without what may differ: timings, options, and the evaluation count (two
    workers may both draw a point that one serial search draws once)."""
    return {k: v for k, v in report.items() if k not in ("timing_s", "options", "evaluations")}


def _null_fit_every_candidate(top, residual_real, null_gains):
    """``analysis.declare`` for this test: fit every candidate on the null (the real one skips
    those whose held-out interval reaches zero, which depends on the realisation) and declare none."""
    for c in top:
        c["declared"] = False
        c["null_gains"] = list(null_gains(c))
    return None


def test_two_worker_processes_give_the_serial_report(tmp_path, monkeypatch):
    path = record("time_offset", tmp_path)
    # a physics candidate (re-simulated in the workers) and an observation one (re-drawn); the
    # calibration's trials run in the workers, the planted offset makes the residual real, and
    # every candidate is fitted on the null there too (decided here, in this process)
    opts = dict(candidates=("drag", "time_offset"), top=2, null_runs=1, level_runs=3, bootstrap=200)
    monkeypatch.setattr(analysis, "declare", _null_fit_every_candidate)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)           # as each worker: the same float rounding
    try:
        serial = analyse([path], options=Options(**opts))
        parallel = analyse([path], options=Options(**opts, jobs=2))
    finally:
        torch.set_num_threads(threads)
    assert serial["null"]["residual_real"], "the case must exercise the null fits"
    checked = [c for c in serial["candidates"] if c.get("null_gains")]
    assert len(checked) == 2
    # the level is read off 3 realisations, the candidates are fitted on the first one only
    assert serial["null"]["level_runs"] == len(serial["null"]["base_heldout_loss"]) == 3
    assert all(len(c["null_gains"]) == 1 for c in checked)
    assert _comparable(parallel) == _comparable(serial)
    assert parallel["options"]["jobs"] == 2 and parallel["evaluations"] >= serial["evaluations"]


@pytest.mark.parametrize("jobs", [0, -1, 1.5, True])
def test_jobs_must_be_a_positive_whole_number(jobs):
    with pytest.raises(ValueError, match="jobs"):
        Options(jobs=jobs)
