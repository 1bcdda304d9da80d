"""Model evaluations of a discrepancy analysis spread over worker processes.

The analysis is a chain of searches (calibration, candidate fits, refinements, fits on the
null realisations), and each search point is a rollout of the model plus its drawing.
:class:`Workers` runs them in ``jobs`` spawned processes, each holding its own
:class:`~.rollout.Simulator` of every episode, and hands back every evaluation (coarse cells
and pixel IOU per episode, keyed by the extension). The analysis merges them into its own
cache and then runs its unchanged serial code, whose every evaluation is now a cache hit:
the searches are deterministic, so they visit the same points, and the report is what the
serial analysis gives (bit for bit when both run torch on one thread, as each worker does).

Candidate fits are scheduled point by point (:meth:`Workers.fit`): the searches run in this
process as generators (``candidates.search``) that yield batches of independent points, and
each point is one task, given to the first free worker, follow-up points of a search ahead
of fresh grid points. A search is then as long as its chain of batches, not its number of
points, and the workers are not left idle while one long search (wind: 14 rollouts) ends.
Observation candidates (time and camera offsets) re-draw one rollout, so their whole search
stays one task.

What crosses between the processes is the analysis's own data (episodes, extensions, numpy
arrays) through ``multiprocessing``'s local pipes; nothing is read from outside. A worker that
dies (killed, out of memory) stops the analysis with :class:`~liquidtwin.procs.WorkerDied`
instead of leaving it waiting for the lost answer (``liquidtwin.procs``).
"""

from __future__ import annotations

import heapq
import itertools
import queue

from .. import procs

#: What a dead worker's error names.
WHAT = "the discrepancy analysis"

#: The worker's evaluator (one per process, built by :func:`_init`).
_EV = None


def _init(eps, frames, extra_iterations, jitter, mass_fit=()) -> None:
    global _EV
    import torch

    from .analysis import _Evaluator
    from .rollout import Simulator
    torch.set_num_threads(1)
    _EV = _Evaluator([Simulator(e, extra_iterations=extra_iterations, jitter=jitter) for e in eps], None, mass_fit)
    _EV.restrict(frames)


def _run(task) -> tuple:
    """One task in a worker: ("cells", ext, seed) draws one extension; ("group", exts, seed)
    draws several in order (an observation candidate's re-draws after their rollout); ("fit", name, rounds,
    base, cells, fit, seed) runs ``fit_candidate`` against observed ``cells`` on the ``fit``
    frames; ("null", run, seed_value, base, vary, seed) draws one null realisation. ``seed``: cache
    entries to start from. Returns (result, the entries computed here)."""
    from .analysis import _Data, _null_cells
    from .candidates import fit_candidate
    ev = _EV
    kind, *args, seed = task
    ev.preload(seed)
    result = None
    if kind == "cells":
        ev.cells(args[0])
    elif kind == "group":
        for ext in args[0]:
            ev.cells(ext)
    elif kind == "fit":
        name, rounds, base, cells, fit = args
        data = _Data(cells, fit, None, None)
        ext, _, _ = fit_candidate(name, lambda e: ev.objective(e, data), base, rounds, ev.upper(name))
        ev.cells(ext)
    elif kind == "null":
        run, seed_value, base, vary = args
        result = _null_cells(ev.sims, ev.frames, base, run, seed_value, vary, clean=True)
    else:
        raise ValueError(f"unknown task {kind!r}")
    return result, ev.take_fresh()


class Workers:
    """``jobs`` spawned processes evaluating for the analysis's :class:`_Evaluator` ``ev``."""

    def __init__(self, ev, eps, frames, jobs: int, extra_iterations: int = 0, jitter: float = 0.0,
                 mass_fit=()):
        self.ev = ev
        self.jobs = jobs
        self.pool = procs.pool(jobs, initializer=_init,
                               initargs=(list(eps), list(frames), extra_iterations, jitter, tuple(mass_fit)))

    def _start(self, tasks: list):
        """Hand ``tasks`` to the workers now; returns a call that waits for their results (in
        order), merging the evaluations they made."""
        futures = [self.pool.submit(_run, t) for t in tasks]

        def wait() -> list:
            out = []
            for future in futures:
                result, fresh = procs.result(future, WHAT)
                self.ev.merge(fresh)
                out.append(result)
            return out
        return wait

    def draw(self, exts) -> None:
        """Evaluate every extension of ``exts`` (into the cache)."""
        self._start([("cells", e, {}) for e in exts])()

    def draw_groups(self, groups) -> None:
        """Evaluate every list of extensions of ``groups``, each list in order in one worker."""
        self._start([("group", list(g), {}) for g in groups])()

    def fit(self, searches, rounds: int, base: dict, fit: list) -> None:
        """Run the search of every (candidate name, observed cells) of ``searches`` on the
        ``fit`` frames (into the cache), point by point (module doc)."""
        from .analysis import _Data
        from .candidates import LIBRARY, search
        ev = self.ev
        ready: list = []                # heap of (-depth, seq, task, key): deeper searches first
        seq = itertools.count()
        inflight: set = set()           # keys being evaluated (an extension's, or a whole search's)
        gens, datas, depths, waiting = {}, {}, {}, {}
        done: queue.SimpleQueue = queue.SimpleQueue()

        def want(ext, depth: int) -> None:
            k = ev.key(ext)
            if not ev.has(ext) and k not in inflight:
                inflight.add(k)
                heapq.heappush(ready, (-depth, next(seq), ("cells", ext, {}), k))

        def advance(i: int, values) -> None:
            """Send search i its batch's losses; queue what its next batch lacks."""
            while True:
                try:
                    batch = gens[i].send(values)
                except StopIteration:
                    return
                if all(ev.has(e) for e in batch):
                    values = [ev.objective(e, datas[i]) for e in batch]
                    continue
                waiting[i] = batch
                depths[i] += 1
                for e in batch:
                    want(e, depths[i])
                return

        for i, (name, cells) in enumerate(searches):
            if LIBRARY[name].observation:
                heapq.heappush(ready, (-1, next(seq), ("fit", name, rounds, dict(base), cells, fit, ev.entries(name)),
                                       ("search", i)))
            else:
                gens[i], datas[i], depths[i] = search(name, base, rounds, ev.upper(name)), _Data(cells, fit, None, None), 0
        for i in list(gens):
            advance(i, None)
        running = 0
        while ready or running:
            while ready and running < self.jobs:
                _, _, task, k = heapq.heappop(ready)
                # a dead worker fails its future too, so this wait always ends
                self.pool.submit(_run, task).add_done_callback(lambda f, k=k: done.put((k, f)))
                running += 1
            k, future = done.get()
            running -= 1
            ev.merge(procs.result(future, WHAT)[1])
            inflight.discard(k)
            for i, batch in list(waiting.items()):
                if all(ev.has(e) for e in batch):
                    del waiting[i]
                    advance(i, [ev.objective(e, datas[i]) for e in batch])
        if waiting:                     # cannot happen: every wanted point was queued
            raise RuntimeError(f"searches {sorted(waiting)} were left waiting")

    def null_cells(self, runs: int, seed: int, base, vary: bool = True):
        """Start :func:`~.analysis._null_cells` of runs 0 … ``runs`` − 1 (with their clean cells);
        returns a call that waits for them (the list, in run order), so this process can work
        meanwhile."""
        return self._start([("null", r, seed, base, vary, {}) for r in range(runs)])

    def close(self, abort: bool = False) -> None:
        """Wait for the workers to exit (``abort``: stop them now, e.g. after an error)."""
        if abort:
            procs.stop(self.pool)
        else:
            self.pool.shutdown(wait=True)
