"""The candidate library: each named cause, its parameters, and how they are fitted.

Every candidate is fitted by the same rule: a coarse search over the parameter's realistic
range (log-spaced where the parameter is a rate), then refinement between the best value and
its neighbours; the refined estimate is the minimum of a parabola through the best point and
its neighbours, not the best point itself (the losses are noisy: see :func:`_vertex`). Every
evaluation is a full open-loop rollout of the extended model through the fitting frames
(physics and initial-fill candidates) or a re-drawing of the base rollout (observation
candidates: time and camera offsets change what the camera shows, not the liquid).

``objective(ext) -> float`` is supplied by the analysis (mean fitting loss of the extension).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Generator

import numpy as np

from .model import CANDIDATES, OBSERVATION, Extension

#: Refinement rounds after the coarse grid (each halves the bracket: 2 evaluations): every
#: candidate gets ``COARSE``, the best few are refined to ``FINE``.
COARSE = 1
FINE = 3


@dataclass(frozen=True)
class Candidate:
    name: str
    doc: str
    grid: tuple            # coarse values of the main parameter
    key: str               # its name in Extension.params
    log: bool = False

    @property
    def observation(self) -> bool:
        return self.name in OBSERVATION


LIBRARY = {c.name: c for c in (
    Candidate("drag", "quadratic air drag on fast particles, a = −c|v|v", (0.4, 1.2, 3.0, 7.0), "c", True),
    Candidate("wind", "uniform horizontal acceleration (ax, az)", (1.2,), "a"),
    Candidate("viscosity", "XSPH viscosity λ_v other than calibrated", (8.0, 20.0, 110.0, 160.0), "lambda_v", True),
    Candidate("cohesion", "cohesion λ_c other than calibrated", (0.03, 0.2, 0.35, 0.55), "lambda_c", True),
    Candidate("wall_adhesion", "particles within a spacing of a wall slowed at rate k", (5.0, 15.0, 35.0, 70.0), "k", True),
    Candidate("leak", "a hole in the source container's wall", (0.003, 0.005, 0.008), "radius"),
    Candidate("blockage", "part of the source's opening blocked on the pouring side", (0.4, 0.7, 1.0), "fraction"),
    Candidate("fill_error", "true initial fill = stated × (1 + value), at most to the rim", (-0.4, -0.2, 0.2, 0.4), "value"),
    Candidate("time_offset", "images stamped t show time t − s",
              tuple(np.round(np.arange(-0.3, 0.3001, 0.05), 3).tolist()), "s"),
    Candidate("camera_offset", "stated camera rotated by (rx, ry, rz) deg", (-2.4, -1.2, 1.2, 2.4), "r"),
)}
assert tuple(LIBRARY) == CANDIDATES

#: Leak sites tried (height as a share of the liquid depth, azimuth from +x; the lip is at 180°).
LEAK_SITES = ((0.4, 150.0), (0.4, 180.0), (0.4, 210.0))
WIND_DIRECTIONS = 8


def _ext(name: str, base: dict, **params) -> Extension:
    return Extension(name, {k: float(v) for k, v in params.items()}, dict(base))


def _vertex(trace: list, log: bool) -> float | None:
    """The minimum of a parabola fitted (least squares) to the best point of ``trace``
    [(x, f), …] and up to two points on each side of it, in log x where ``log`` (and every x
    > 0); clamped to those points' span. None when fewer than 3 points or the parabola opens
    downwards. Each evaluation is a chaotic rollout, so f is noisy: the argmin of the points
    picks noise as much as the minimum, the parabola averages over its neighbours."""
    xs = sorted(trace)
    k = min(range(len(xs)), key=lambda i: xs[i][1])
    sel = xs[max(0, k - 2): k + 3]
    if len(sel) < 3:
        return None
    x = np.array([t[0] for t in sel], float)
    y = np.array([t[1] for t in sel], float)
    use_log = log and bool((x > 0).all())
    z = np.log(x) if use_log else x
    if np.ptp(z) <= 0 or not np.isfinite(y).all():
        return None
    a, b, _ = np.polyfit((z - z.mean()) / np.ptp(z), y, 2)
    if not a > 0:
        return None
    zv = float(np.clip(z.mean() - b / (2 * a) * np.ptp(z), z.min(), z.max()))
    return math.exp(zv) if use_log else zv


def drive(search: Generator, evaluate: Callable[[list], list]):
    """Run a search generator (:func:`search`, :func:`_line_points`) to its end: every batch it
    yields is answered with ``evaluate(batch)`` (a list of the same length); returns the
    generator's value."""
    try:
        batch = next(search)
        while True:
            batch = search.send(list(evaluate(batch)))
    except StopIteration as done:
        return done.value


def _line_points(run: Callable[[list], Generator], grid, log: bool, rounds: int = COARSE) -> Generator:
    """:func:`_line` as a search generator over points x: ``run(xs)`` is a generator that
    yields the batch for xs and returns their losses. The grid is one batch, each refinement
    round's (up to two) new points another: the points of a batch do not depend on each other."""
    trace = list(zip((float(g) for g in grid), (yield from run([float(g) for g in grid]))))
    for _ in range(rounds):
        xs = sorted(trace)
        k = min(range(len(xs)), key=lambda i: xs[i][1])
        mids = []
        for j in (k - 1, k + 1):
            if 0 <= j < len(xs):
                a, b = xs[k][0], xs[j][0]
                mid = math.sqrt(a * b) if (log and a > 0 and b > 0) else 0.5 * (a + b)
                if all(abs(mid - t) > 1e-9 for t in [t[0] for t in trace] + mids):
                    mids.append(mid)
        if mids:
            trace += list(zip(mids, (yield from run(mids))))
    x, fx = min(trace, key=lambda t: t[1])
    v = _vertex(trace, log) if rounds > COARSE else None
    if v is not None:
        x, fx = v, (yield from run([v]))[0]
    return x, fx, trace


def _line(f: Callable[[float], float], grid, log: bool, rounds: int = COARSE) -> tuple[float, float, list]:
    """Minimise f over ``grid`` then refine ``rounds`` times around the best point (bisecting
    towards both neighbours). Returns (x, f(x), trace): x is the best point of the trace after
    the coarse grid alone; after refinement, the parabola's minimum (:func:`_vertex`) where
    there is one."""
    def run(xs):
        return (yield xs)
    return drive(_line_points(run, grid, log, rounds), lambda xs: [f(x) for x in xs])


def search(name: str, base: dict, rounds: int = COARSE, upper: float | None = None) -> Generator:
    """The fit of candidate ``name`` (:func:`fit_candidate`) as a generator: it yields batches
    (lists) of Extensions whose fitting losses it needs, is sent their losses, and returns
    (extension, its loss, trace). The extensions of one batch do not depend on each other's
    losses, so a caller may evaluate them at once (``parallel``); the batches, and so the
    result, are those of the serial fit."""
    c = LIBRARY[name]
    trace = []

    def run(points: list) -> Generator:
        """Evaluate params dicts ``points`` as one batch, recording them in the trace."""
        exts = [_ext(name, base, **p) for p in points]
        vals = [float(v) for v in (yield exts)]
        trace.extend((dict(e.params), v) for e, v in zip(exts, vals))
        return vals

    def line(point: Callable[[float], dict], grid, log: bool) -> Generator:
        return _line_points(lambda xs: run([point(x) for x in xs]), grid, log, rounds)

    if name == "wind":
        dirs = [2 * math.pi * k / WIND_DIRECTIONS for k in range(WIND_DIRECTIONS)]
        a0 = c.grid[0]
        scores = yield from run([dict(ax=a0 * math.cos(t), az=a0 * math.sin(t)) for t in dirs])
        t = dirs[int(np.argmin(scores))]
        # refine the azimuth between the best and its better neighbour, then the magnitude
        k = int(np.argmin(scores))
        nb = dirs[(k + 1) % WIND_DIRECTIONS] if scores[(k + 1) % WIND_DIRECTIONS] < scores[k - 1] else dirs[k - 1]
        tm = math.atan2(math.sin(t) + math.sin(nb), math.cos(t) + math.cos(nb))
        if (yield from run([dict(ax=a0 * math.cos(tm), az=a0 * math.sin(tm))]))[0] < min(scores):
            t = tm
        a, _, _ = yield from line(lambda a: dict(ax=a * math.cos(t), az=a * math.sin(t)), (0.5, a0, 2.4), True)
        params = {"ax": a * math.cos(t), "az": a * math.sin(t)}
    elif name == "leak":
        r0 = c.grid[1]
        scores = yield from run([dict(radius=r0, height_fraction=s[0], azimuth_deg=s[1]) for s in LEAK_SITES])
        site = LEAK_SITES[int(np.argmin(scores))]          # the first of equal losses, as min() takes
        r, _, _ = yield from line(lambda r: dict(radius=r, height_fraction=site[0], azimuth_deg=site[1]),
                                  (0.003, 0.008), False)
        params = {"radius": r, "height_fraction": site[0], "azimuth_deg": site[1]}
    elif name == "camera_offset":
        r = [0.0, 0.0, 0.0]
        for k in range(1 + (rounds > COARSE)):         # coordinate descent over the three axes
            for axis in range(3):
                def point(v, axis=axis):
                    rr = list(r)
                    rr[axis] = v
                    return dict(rx=rr[0], ry=rr[1], rz=rr[2])
                grid = c.grid if k == 0 else (r[axis] - 0.6, r[axis] + 0.6)
                v, _, _ = yield from line(point, tuple(grid) + (r[axis],), False)
                r[axis] = v
        params = {"rx": r[0], "ry": r[1], "rz": r[2]}
    else:
        grid = c.grid if upper is None else tuple(sorted({min(float(g), float(upper)) for g in c.grid}))
        v, _, _ = yield from line(lambda v: {c.key: v}, grid, c.log)
        params = {c.key: v}
    if rounds <= COARSE:                               # coarse: the best point tried
        params = min(trace, key=lambda t: t[1])[0]
    ext = _ext(name, base, **params)
    loss = float((yield [ext])[0])                     # cached by the analysis where tried
    return ext, loss, trace


def fit_candidate(name: str, objective: Callable[[Extension], float], base: dict,
                  rounds: int = COARSE, upper: float | None = None) -> tuple[Extension, float, list]:
    """Fit candidate ``name`` with ``rounds`` refinements after the coarse grid; returns (the
    extension: after the coarse grid alone its best point tried, after refinement the last
    line search's parabola minimum; its fitting loss; [(params, loss), …]). The analysis
    caches evaluations, so a finer fit after a coarse one only pays for its new points.
    ``upper``: the largest value of a one-parameter candidate's main parameter that still
    changes the model (grid points above it are moved onto it), e.g. the fill error that fills
    the source to its rim."""
    return drive(search(name, base, rounds, upper), lambda exts: [objective(e) for e in exts])


def tied_range(name: str, trace: list, base: dict | None = None, rtol: float = 1e-9) -> tuple[float, float] | None:
    """(lowest, highest) main value among the tried points whose fitting loss equals the best
    one's (to ``rtol``): the values the recording cannot tell apart, because the rollouts
    agree on every frame the loss sees. None when only one value reaches the best loss. A
    blockage plate that already covers the pouring lip, for instance, holds the same liquid
    back at any larger fraction."""
    if not trace:
        return None
    best = min(v for _, v in trace)
    vals = sorted({main_value(_ext(name, base or {}, **p)) for p, v in trace
                   if abs(v - best) <= rtol * max(1.0, abs(best))})
    return (vals[0], vals[-1]) if len(vals) > 1 else None


def main_value(ext: Extension) -> float:
    """The one magnitude compared with a planted effect's ``value`` (its unit)."""
    p = ext.params
    if ext.name == "wind":
        return math.hypot(p["ax"], p["az"])
    if ext.name == "camera_offset":
        return math.sqrt(p["rx"] ** 2 + p["ry"] ** 2 + p["rz"] ** 2)
    return float(p[LIBRARY[ext.name].key])
