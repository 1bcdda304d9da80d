"""Shared by the blind discrepancy tests (one file per case, so that pytest-xdist runs the
cases side by side): the planted cases, the magnitudes, and the sidecar reader — which the
tests open only after the analysis, to score it."""

import json

import numpy as np

from liquidtwin.generate import generate

#: (planted effect or None, seed): quick pour_hold, cup 90 % full, target drawn by the seed.
CASES = {"none": (None, 7), "time_offset": ("time_offset", 9)}


def upper_range_value(name: str, seed: int) -> float:
    """A magnitude in the upper 40 % of one of the effect's realistic ranges (sign by the seed)."""
    from liquidtwin.generate.effects import EFFECTS
    rng = np.random.default_rng([seed, 6])
    ranges = EFFECTS[name].ranges
    lo, hi = ranges[int(rng.integers(len(ranges)))]
    far, near = (lo, hi) if abs(lo) > abs(hi) else (hi, lo)        # the larger magnitude end
    return float(far + rng.uniform(0.0, 0.4) * (near - far))


def record(case: str, directory):
    """Generate the case's recording (+ truth sidecar) into ``directory``; returns its path."""
    effect, seed = CASES[case]
    path = directory / f"{case}.mcap"
    effects = [(effect, upper_range_value(effect, seed))] if effect else []
    generate("pour_hold", path, effects=effects, seed=seed, quick=True, choices={"source": "cup", "fraction": 0.9})
    return path


def truth(path):
    """The sidecar — read only after the analysis, to score it."""
    return json.loads(path.with_suffix(".truth.json").read_text())["effect"]


def candidate(report, name):
    return next(c for c in report["candidates"] if c["name"] == name)
