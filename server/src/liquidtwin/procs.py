"""Work spread over spawned worker processes, with a clear error when a worker dies.

``multiprocessing.Pool`` waits forever for the answer of a worker that was killed (out of
memory, a signal, a crash in native code): the task is lost and the pool starts a fresh
worker in its place. The benchmarks, trainings and analyses here run for minutes to hours,
so they use :class:`concurrent.futures.ProcessPoolExecutor`, which fails every pending task
when one of its workers dies; :func:`result` turns that into :class:`WorkerDied`, which says
what happened and what to try. Workers are spawned (not forked): each starts a fresh
interpreter, so no torch thread pool or open session is copied into it.
"""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool


class WorkerDied(RuntimeError):
    """A worker process ended without answering (killed, out of memory, a native crash, or
    its start-up failed); the work it held is lost."""


def pool(jobs: int, initializer=None, initargs: tuple = ()) -> ProcessPoolExecutor:
    """``jobs`` spawned worker processes, each starting with ``initializer(*initargs)``."""
    return ProcessPoolExecutor(jobs, mp_context=mp.get_context("spawn"), initializer=initializer, initargs=initargs)


def result(future: Future, what: str):
    """``future.result()``, with a dead worker reported as :class:`WorkerDied` naming ``what``
    (an exception raised by the task itself comes through as it is)."""
    try:
        return future.result()
    except BrokenProcessPool as e:
        raise WorkerDied(f"a worker process of {what} died without answering ({e}): killed, out of memory, "
                         "or a crash in native code; its work is lost. Run again with fewer jobs "
                         "(1 runs everything in this process)") from e


def stop(executor: ProcessPoolExecutor) -> None:
    """Stop ``executor`` now: drop the tasks not started and end the running workers (their
    results are not wanted). Python 3.14 has ``terminate_workers`` for this; before it, the
    executor's process table is the only handle on them."""
    procs = list((getattr(executor, "_processes", None) or {}).values())
    executor.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(10)


def map_jobs(fn, work, jobs: int, *, ordered: bool = True, what: str = "this run"):
    """``fn`` over ``work`` in ``jobs`` spawned processes (in this process, in order, when
    ``jobs`` <= 1 or there is one item). Yields the results in the order of ``work``, or as
    they finish when not ``ordered``. A worker that dies raises :class:`WorkerDied` at once;
    leaving early stops the workers."""
    work = list(work)
    if jobs <= 1 or len(work) <= 1:
        yield from map(fn, work)
        return
    ex = pool(min(jobs, len(work)))
    futures: list = []
    try:
        futures = [ex.submit(fn, w) for w in work]
        for f in (futures if ordered else as_completed(futures)):
            yield result(f, what)
    finally:
        # Every task done (also when the caller stopped at the last result, as zip does):
        # the workers exit on their own and run their clean-up; a worker terminated instead
        # leaves its semaphores (tqdm's lock) to the resource tracker's "leaked" warning.
        if futures and all(f.done() for f in futures):
            ex.shutdown(wait=True)
        else:
            stop(ex)
