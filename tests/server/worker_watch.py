"""Shared by the tests of worker processes: run a call that must not hang, and wait for the
workers to be gone."""

import multiprocessing as mp
import threading
import time


def within(seconds, fn):
    """fn() in a thread, which must end within ``seconds`` (a hang fails the test, not the run);
    returns what it returned or raised."""
    out = {}

    def run():
        try:
            out["value"] = fn()
        except BaseException as e:      # noqa: BLE001 — handed to the test
            out["error"] = e
    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"still waiting after {seconds} s"
    return out


def no_workers_left(seconds=10.0):
    """Whether this process's worker processes are all gone within ``seconds``."""
    end = time.monotonic() + seconds
    while mp.active_children() and time.monotonic() < end:
        time.sleep(0.1)
    return not mp.active_children()
