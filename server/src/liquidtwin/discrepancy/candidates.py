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
from typing import Callable

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


def _line(f: Callable[[float], float], grid, log: bool, rounds: int = COARSE) -> tuple[float, float, list]:
    """Minimise f over ``grid`` then refine ``rounds`` times around the best point (bisecting
    towards both neighbours). Returns (x, f(x), trace): x is the best point of the trace after
    the coarse grid alone; after refinement, the parabola's minimum (:func:`_vertex`) where
    there is one."""
    trace = [(float(g), f(float(g))) for g in grid]
    for _ in range(rounds):
        xs = sorted(trace)
        k = min(range(len(xs)), key=lambda i: xs[i][1])
        for j in (k - 1, k + 1):
            if 0 <= j < len(xs):
                a, b = xs[k][0], xs[j][0]
                mid = math.sqrt(a * b) if (log and a > 0 and b > 0) else 0.5 * (a + b)
                if all(abs(mid - t[0]) > 1e-9 for t in trace):
                    trace.append((mid, f(mid)))
    x, fx = min(trace, key=lambda t: t[1])
    v = _vertex(trace, log) if rounds > COARSE else None
    if v is not None:
        x, fx = v, f(v)
    return x, fx, trace


def fit_candidate(name: str, objective: Callable[[Extension], float], base: dict,
                  rounds: int = COARSE, upper: float | None = None) -> tuple[Extension, float, list]:
    """Fit candidate ``name`` with ``rounds`` refinements after the coarse grid; returns (the
    extension: after the coarse grid alone its best point tried, after refinement the last
    line search's parabola minimum; its fitting loss; [(params, loss), …]). The analysis
    caches evaluations, so a finer fit after a coarse one only pays for its new points.
    ``upper``: the largest value of a one-parameter candidate's main parameter that still
    changes the model (grid points above it are moved onto it), e.g. the fill error that fills
    the source to its rim."""
    c = LIBRARY[name]
    trace = []

    def run(**params) -> float:
        ext = _ext(name, base, **params)
        val = float(objective(ext))
        trace.append((dict(ext.params), val))
        return val

    if name == "wind":
        dirs = [2 * math.pi * k / WIND_DIRECTIONS for k in range(WIND_DIRECTIONS)]
        a0 = c.grid[0]
        scores = [run(ax=a0 * math.cos(t), az=a0 * math.sin(t)) for t in dirs]
        t = dirs[int(np.argmin(scores))]
        # refine the azimuth between the best and its better neighbour, then the magnitude
        k = int(np.argmin(scores))
        nb = dirs[(k + 1) % WIND_DIRECTIONS] if scores[(k + 1) % WIND_DIRECTIONS] < scores[k - 1] else dirs[k - 1]
        tm = math.atan2(math.sin(t) + math.sin(nb), math.cos(t) + math.cos(nb))
        if run(ax=a0 * math.cos(tm), az=a0 * math.sin(tm)) < min(scores):
            t = tm
        a, _, _ = _line(lambda a: run(ax=a * math.cos(t), az=a * math.sin(t)), (0.5, a0, 2.4), True, rounds)
        params = {"ax": a * math.cos(t), "az": a * math.sin(t)}
    elif name == "leak":
        r0 = c.grid[1]
        site = min(LEAK_SITES, key=lambda s: run(radius=r0, height_fraction=s[0], azimuth_deg=s[1]))
        r, _, _ = _line(lambda r: run(radius=r, height_fraction=site[0], azimuth_deg=site[1]), (0.003, 0.008), False,
                        rounds)
        params = {"radius": r, "height_fraction": site[0], "azimuth_deg": site[1]}
    elif name == "camera_offset":
        r = [0.0, 0.0, 0.0]
        for k in range(1 + (rounds > COARSE)):         # coordinate descent over the three axes
            for axis in range(3):
                def f(v, axis=axis):
                    rr = list(r)
                    rr[axis] = v
                    return run(rx=rr[0], ry=rr[1], rz=rr[2])
                grid = c.grid if k == 0 else (r[axis] - 0.6, r[axis] + 0.6)
                v, fv, tr = _line(f, tuple(grid) + (r[axis],), False, rounds)
                r[axis] = v
        params = {"rx": r[0], "ry": r[1], "rz": r[2]}
    else:
        grid = c.grid if upper is None else tuple(sorted({min(float(g), float(upper)) for g in c.grid}))
        v, _, _ = _line(lambda v: run(**{c.key: v}), grid, c.log, rounds)
        params = {c.key: v}
    if rounds <= COARSE:                               # coarse: the best point tried
        params = min(trace, key=lambda t: t[1])[0]
    loss = float(objective(_ext(name, base, **params)))   # cached by the analysis where tried
    return _ext(name, base, **params), loss, trace


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
