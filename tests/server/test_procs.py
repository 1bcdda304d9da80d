"""Worker processes (``liquidtwin.procs``): results in order, a task's own error comes back as
it is, and a worker that dies stops the run with a clear error instead of a wait forever
(which is what ``multiprocessing.Pool`` does: the killed worker's task is never answered)."""

import os
import time
from pathlib import Path

import pytest
from worker_watch import no_workers_left, within

from liquidtwin.procs import WorkerDied, map_jobs


def _square_and_pid(x):
    return x * x, os.getpid()


def _fail_on_three(x):
    if x == 3:
        raise ValueError(f"task {x} refused")
    return x


def _die_on_three(x):
    if x == 3:
        os._exit(7)             # as a kill or the out-of-memory killer would: no answer, no exception
    time.sleep(0.2)
    return x


def _slow(x):
    if x:
        time.sleep(60)
    return x


def _mark_clean_exit(job):
    """Register, in the worker, a clean-up that writes a marker when the worker exits on its
    own (a terminated worker runs none: its semaphores were left to the resource tracker)."""
    import multiprocessing.util
    folder, x = job
    marker = Path(folder) / f"exited-{os.getpid()}"
    if not getattr(_mark_clean_exit, "registered", False):
        multiprocessing.util.Finalize(None, marker.write_text, args=("clean",), exitpriority=10)
        _mark_clean_exit.registered = True
    time.sleep(0.2)
    return x, os.getpid()


def test_a_caller_that_stops_at_the_last_result_lets_the_workers_exit_cleanly(tmp_path):
    """``zip(cases, map_jobs(...))`` stops at the last result without finishing the generator;
    the workers used to be terminated then, and the resource tracker warned of leaked semaphores
    at exit (``evaluate discrepancy --jobs 2``)."""
    cases = ["a", "b", "c", "d"]
    got = [(c, r, pid) for c, (r, pid) in zip(cases, map_jobs(_mark_clean_exit, [(str(tmp_path), i) for i in range(4)], 2))]
    assert [(c, r) for c, r, _ in got] == list(zip(cases, range(4)))
    assert within(30, no_workers_left) == {"value": True}
    marked = {int(m.name.split("-")[1]) for m in tmp_path.glob("exited-*")}
    assert marked == {pid for _, _, pid in got}, "every worker ran its clean-up: it exited on its own"


def test_results_come_in_order_from_other_processes_or_as_they_finish():
    out = list(map_jobs(_square_and_pid, range(6), 2))
    assert [r for r, _ in out] == [0, 1, 4, 9, 16, 25]
    assert os.getpid() not in {pid for _, pid in out}
    unordered = [r for r, _ in map_jobs(_square_and_pid, range(6), 2, ordered=False)]
    assert sorted(unordered) == [0, 1, 4, 9, 16, 25]
    # one job, or one item: here, in this process
    assert {pid for _, pid in map_jobs(_square_and_pid, range(3), 1)} == {os.getpid()}
    assert no_workers_left()


def test_an_error_raised_by_a_task_comes_back_as_it_is():
    with pytest.raises(ValueError, match="task 3 refused"):
        list(map_jobs(_fail_on_three, range(6), 2))
    assert no_workers_left()


def test_a_worker_that_dies_stops_the_run_with_a_clear_error():
    out = within(60, lambda: list(map_jobs(_die_on_three, range(8), 2, what="the test run")))
    assert isinstance(out.get("error"), WorkerDied), out
    message = str(out["error"])
    assert "the test run" in message and "fewer jobs" in message
    assert no_workers_left()


def test_leaving_early_stops_the_workers_at_once():
    def first():
        results = map_jobs(_slow, range(4), 2)
        value = next(results)           # task 0 answers at once; 1 and 2 sleep a minute
        results.close()
        return value
    assert within(30, first) == {"value": 0}       # not the minute the sleeping tasks would take
    assert no_workers_left()


def test_the_cli_reports_a_dead_worker_in_one_line(monkeypatch, capsys):
    import dataclasses

    from liquidtwin import cli

    def dies(args):
        raise WorkerDied("a worker process of the discrepancy analysis died without answering")
    monkeypatch.setitem(cli.COMMANDS, "discrepancy", dataclasses.replace(cli.COMMANDS["discrepancy"], run=dies))
    assert cli.main(["discrepancy", "rec.mcap", "--out", "report"]) == 3
    err = capsys.readouterr().err
    assert err.strip() == "liquidtwin discrepancy: a worker process of the discrepancy analysis died without answering"
