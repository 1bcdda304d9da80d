"""Dropped camera / tracker frames: isolated losses and occasional bursts.

A two-state Markov chain (Gilbert model): from a kept frame the next one is dropped with
probability p, from a dropped frame the next one is dropped again with probability
1 − 1/burst. Burst lengths are geometric with mean ``burst`` frames, and
p = rate / (burst · (1 − rate)) makes the long-run dropped fraction equal ``rate``.
The chain starts in the kept state, so frame 0 is always kept. ``burst = 1`` means drops never
come two in a row; independent (Bernoulli) drops are ``burst = 1 / (1 − rate)``.
"""

from __future__ import annotations

import numpy as np

from ._common import SensorInputError, check_generator, check_number


def dropped_frames(n_frames: int, rng: np.random.Generator, *, rate: float = 0.03,
                   burst: float = 2.0) -> np.ndarray:
    """Which frames arrive.

    n_frames: number of frames (≥ 0).
    rng:      numpy Generator (same seed → same output).
    rate:     long-run fraction of dropped frames, [0, burst / (1 + burst)].
    burst:    mean length of a run of dropped frames, frames, ≥ 1.
    Returns keep: (n_frames,) bool, True for frames that arrive; keep[0] is always True.
    """
    rng = check_generator(rng)
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 0:
        raise SensorInputError(f"n_frames must be a non-negative integer, got {n_frames!r}")
    n_frames = int(n_frames)
    burst = check_number("burst", burst, 1.0, 1e6)
    rate = check_number("rate", rate, 0.0, burst / (1.0 + burst))
    if rate == 0.0 or n_frames <= 1:
        return np.ones(n_frames, bool)
    q = 1.0 / burst                        # P(dropped → kept)
    p = rate * q / (1.0 - rate)            # P(kept → dropped)
    pieces, total = [], 0
    while total < n_frames:
        k = int(1.2 * (n_frames - total) * p) + 16      # alternating runs: kept, dropped, ...
        runs = np.empty(2 * k, np.int64)
        runs[0::2] = rng.geometric(p, k)
        runs[1::2] = rng.geometric(q, k)
        states = np.tile(np.array([True, False]), k)
        pieces.append(np.repeat(states, runs))
        total += int(runs.sum())
    return np.concatenate(pieces)[:n_frames]
