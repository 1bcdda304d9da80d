"""Discrepancy discovery in worker processes (``Options.jobs``) gives the serial report: the
workers run the same searches, the analysis replays them from their evaluations."""

import multiprocessing as mp
import os
import signal
import threading
import time
from concurrent.futures import Future

import pytest
import torch
from blind_cases import record
from worker_watch import no_workers_left, within

from liquidtwin.discrepancy import Options, analyse
from liquidtwin.discrepancy import analysis

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


def _comparable(report: dict) -> dict:
    """The report without what may differ: timings, options, and the evaluation count (two
    workers may both draw a point that one serial search draws once)."""
    return {k: v for k, v in report.items() if k not in ("timing_s", "options", "evaluations")}


def _null_fit_every_candidate(top, residual_real, null_gains, *, bar):
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
    # one rollout per model here (ensemble 0); the ensembles' draws have the test below
    opts = dict(candidates=("drag", "time_offset"), top=2, null_runs=1, level_runs=3, bootstrap=200, reference="best",
                ensemble=0)
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
    assert all(len(c["null_gains"]) == len(c["null_fitted"]) == 1 for c in checked)
    # the drag's gains are measured from the best of the base rollout and its 3 realisations
    ref = serial["reference"]
    assert ref["kind"] == "best" and ref["predictions"] == 4
    assert ref["which"] in ("base", "realisation 0", "realisation 1", "realisation 2")
    assert ref["heldout_loss"] <= serial["baseline"]["heldout_loss"]
    # … except the time offset's, which re-draws the base rollout (paired, free of its chaos)
    assert {c["name"]: c["reference"] for c in serial["candidates"]} == {"drag": "best", "time_offset": "base"}
    assert _comparable(parallel) == _comparable(serial)
    assert parallel["options"]["jobs"] == 2 and parallel["evaluations"] >= serial["evaluations"]


def test_ensemble_gains_in_workers_give_the_serial_report(tmp_path, monkeypatch):
    """``Options.ensemble``: the best candidates' gains, on the recording and on the null, from
    draws of each prediction; the workers draw them (an offset's re-draws with their rollout).
    Scored here as ``Options.score`` "energy", the default: the workers only draw, and this
    process scores the draws, the energy score as the "distance" score's mean of their losses
    less half their spread (``analysis.ensemble_losses``), so this covers both scores' work in
    the workers (the "distance" case ran here too until stop 68: 96 s for no other path)."""
    path = record("time_offset", tmp_path)
    score = "energy"
    opts = dict(candidates=("drag", "time_offset"), top=2, null_runs=1, level_runs=2, bootstrap=200, ensemble=2,
                score=score)
    monkeypatch.setattr(analysis, "declare", _null_fit_every_candidate)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        serial = analyse([path], options=Options(**opts))
        parallel = analyse([path], options=Options(**opts, jobs=2))
    finally:
        torch.set_num_threads(threads)
    assert _comparable(parallel) == _comparable(serial)
    for c in serial["candidates"]:
        assert c["reference"] == "ensemble" and c["heldout_gain"]["draws"] == 2
        assert c["heldout_gain"]["score"] == score
        assert len(c["null_gains"]) == 1
    assert any(c["single_rollout_gain"]["mean"] != c["heldout_gain"]["mean"] for c in serial["candidates"])
    gains = [c["heldout_gain"]["mean"] for c in serial["candidates"]]
    assert gains == sorted(gains, reverse=True)          # ranked by the ensemble gain


def test_a_worker_killed_mid_analysis_stops_it_with_a_clear_error(tmp_path):
    from liquidtwin.procs import WorkerDied
    path = record("none", tmp_path)
    opts = Options(candidates=("drag", "wind"), top=2, null_runs=1, level_runs=2, bootstrap=100, jobs=2)
    assert no_workers_left()
    killed = []

    def kill_one_when_busy():           # as the out-of-memory killer would, a few s into the work
        end = time.monotonic() + 120
        while time.monotonic() < end:
            workers = mp.active_children()
            if len(workers) == 2:
                time.sleep(3.0)
                os.kill(workers[0].pid, signal.SIGKILL)
                killed.append(workers[0].pid)
                return
            time.sleep(0.05)
    threading.Thread(target=kill_one_when_busy, daemon=True).start()
    out = within(240, lambda: analyse([path], options=opts))
    assert killed, "the analysis ended before a worker could be killed"
    assert isinstance(out.get("error"), WorkerDied), out
    assert "discrepancy analysis" in str(out["error"])
    assert no_workers_left()            # the other worker was stopped too


@pytest.mark.parametrize("jobs", [0, -1, 1.5, True])
def test_jobs_must_be_a_positive_whole_number(jobs):
    with pytest.raises(ValueError, match="jobs"):
        Options(jobs=jobs)


class _Pool:
    """A stand-in for the worker pool: each task is answered at once, in the order given, and
    every submission is logged with how many answers had been read back by then."""

    def __init__(self, done):
        self.done, self.log = done, []

    def submit(self, fn, task):
        kind, ext, _ = task
        assert kind == "cells"
        self.log.append((ext, self.done()))
        future = Future()
        future.set_result((None, {analysis._key(ext): (ext, None)}))
        return future


class _Cache:
    """The evaluator's side of ``Workers.fit``: a cache of extension → loss."""

    def __init__(self, objective):
        self.loss_of, self.store, self.read = objective, {}, 0
        self.key = staticmethod(analysis._key)

    def has(self, ext):
        return analysis._key(ext) in self.store

    def merge(self, entries):
        self.read += 1
        for k, (ext, _) in entries.items():
            assert k not in self.store, "a point was drawn twice"
            self.store[k] = self.loss_of(ext)

    def objective(self, ext, data):
        return self.store[analysis._key(ext)]

    def entries(self, name):
        return {}

    def upper(self, name):
        return None


def test_points_of_a_search_are_drawn_at_once_and_the_fit_is_the_serial_one():
    from liquidtwin.discrepancy.candidates import COARSE, FINE, fit_candidate
    from liquidtwin.discrepancy.parallel import Workers
    import math

    def objective(ext):                 # smooth in the main value, minimum inside the grids
        return sum((math.log(abs(v) + 1e-3) - 0.4) ** 2 for v in ext.params.values())

    for rounds in (COARSE, FINE):
        cache = _Cache(objective)
        w = Workers.__new__(Workers)
        w.ev, w.jobs = cache, 4
        w.pool = _Pool(lambda: cache.read)
        w.fit([("drag", None), ("wind", None)], rounds, {}, None)
        # drag's 4 grid points and wind's first 8 directions go out before any answer is read
        # back (4 at a time: the jobs), and no point is drawn twice (``_Cache.merge``)
        first = [e.name for e, seen in w.pool.log if seen == 0]
        assert first == ["drag"] * 4
        assert sum(1 for e, seen in w.pool.log if seen <= 4) >= 8
        # the serial fits, run against what the workers drew, find every point drawn: same fit
        for name in ("drag", "wind"):
            def cached(ext):
                assert cache.has(ext), f"{name}: the serial search wanted a point the scheduler did not draw"
                return cache.store[analysis._key(ext)]
            ext, loss, trace = fit_candidate(name, cached, {}, rounds)
            assert loss == objective(ext) and len(trace) >= 4
        assert len(cache.store) == len(w.pool.log)


def test_the_workers_fit_the_fill_error_by_the_same_objective(monkeypatch):
    """``Options.fill_fit``: the workers' evaluators are built with the analysis's mass-fitted
    candidates, so their searches visit the points the analysis's own searches do."""
    from liquidtwin import procs
    from liquidtwin.discrepancy import parallel

    started = {}
    monkeypatch.setattr(procs, "pool", lambda jobs, initializer, initargs: started.update(init=initializer, args=initargs))
    monkeypatch.setattr(parallel, "_EV", None)          # this process's, put back afterwards
    threads = torch.get_num_threads()                   # the worker's start sets one thread
    try:
        ev = analysis._Evaluator([], mass_fit=("fill_error",))
        parallel.Workers(ev, [], [], 2, 0, 0.0, ev.mass_fit)
        started["init"](*started["args"])
        assert parallel._EV.mass_fit == {"fill_error"}
        parallel.Workers(ev, [], [], 2)
        started["init"](*started["args"])
        assert parallel._EV.mass_fit == frozenset()
    finally:
        torch.set_num_threads(threads)
