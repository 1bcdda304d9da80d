"""The δ-likelihood of a simulated hypothesis against observed masks (SPEC §3, thesis §7.3.4).

Every pixel of every mask frame is an independent observation: P(j | ĵ) = δ when the
observed label j (liquid / not liquid) equals the hypothesis's predicted label ĵ, 1 − δ when
not. With δ = 0.50001 (the thesis's value, chosen so the product does not underflow) the log
likelihood of one frame is ``agree · log δ + disagree · log(1 − δ)``; hypotheses are compared
through their sums over frames, normalised with a softmax (uniform prior).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Probability that a pixel's observed label equals the predicted one (SPEC §3).
DELTA = 0.50001


def check_delta(delta: float) -> float:
    delta = float(delta)
    if not (0.5 < delta < 1.0):
        raise ValueError(f"delta must be in (0.5, 1): the chance a pixel label agrees with the prediction, got {delta}")
    return delta


def frame_log_likelihood(disagree: int, pixels: int, delta: float = DELTA) -> float:
    """log P(frame | hypothesis) from the count of ``disagree`` pixels out of ``pixels``."""
    delta = check_delta(delta)
    disagree, pixels = int(disagree), int(pixels)
    if not 0 <= disagree <= pixels:
        raise ValueError(f"disagreeing pixels {disagree} must be within 0..{pixels}")
    return (pixels - disagree) * math.log(delta) + disagree * math.log1p(-delta)


def mask_log_likelihood(predicted, observed, delta: float = DELTA) -> float:
    """log P(observed | predicted) for (H, W) bool masks (numpy or torch), in float64."""
    p = np.asarray(predicted.cpu() if hasattr(predicted, "cpu") else predicted, bool)
    o = np.asarray(observed.cpu() if hasattr(observed, "cpu") else observed, bool)
    if p.shape != o.shape or p.ndim != 2:
        raise ValueError(f"predicted {p.shape} and observed {o.shape} masks must both be (H, W)")
    return frame_log_likelihood(int(np.count_nonzero(p != o)), p.size, delta)


def normalise(log_likelihood) -> np.ndarray:
    """Softmax over hypotheses (K,) → probabilities (K,) float64 (uniform prior)."""
    ll = np.asarray(log_likelihood, np.float64)
    if ll.ndim != 1 or ll.size == 0:
        raise ValueError(f"need a (K,) vector of log likelihoods, got shape {ll.shape}")
    if np.isnan(ll).any():
        raise ValueError("a log likelihood is NaN")
    z = ll - ll.max()
    p = np.exp(z)
    return p / p.sum()


@dataclass
class Posterior:
    """The outcome of a hypothesis bank.

    Attributes:
      names: (K,) hypothesis names.
      log_likelihood: (K,) float64 summed δ-log-likelihood over all scored frames.
      probability: (K,) float64 normalised posterior (uniform prior).
      times_s: (T,) float64 time of each scored mask frame, s from the first pose sample.
      probability_over_time: (T, K) float64 posterior after each scored frame.
      frames: T, mask frames scored.
      wall_s: wall time of the whole analysis, s.
      best: name of the most probable hypothesis.
      info: extra facts (tracking mode, camera, particles per hypothesis, batched, …).
    """

    names: list
    log_likelihood: np.ndarray
    probability: np.ndarray
    times_s: np.ndarray
    probability_over_time: np.ndarray
    frames: int
    wall_s: float
    best: str
    info: dict

    @classmethod
    def from_series(cls, names, frame_ll, times_s, wall_s: float, info: dict | None = None) -> "Posterior":
        """From per-frame log likelihoods ``frame_ll`` (T, K) and their ``times_s`` (T,)."""
        names = [str(n) for n in names]
        fl = np.asarray(frame_ll, np.float64).reshape(-1, len(names))
        cum = np.cumsum(fl, 0)
        over = np.stack([normalise(c) for c in cum]) if len(cum) else np.zeros((0, len(names)))
        ll = cum[-1] if len(cum) else np.zeros(len(names))
        prob = normalise(ll)
        return cls(names, ll, prob, np.asarray(times_s, np.float64), over, int(fl.shape[0]), float(wall_s),
                   names[int(np.argmax(prob))], dict(info or {}))

    def as_dict(self) -> dict:
        """Plain JSON-able dict (lists of floats)."""
        return {"names": list(self.names), "log_likelihood": self.log_likelihood.tolist(),
                "probability": self.probability.tolist(), "times_s": self.times_s.tolist(),
                "probability_over_time": self.probability_over_time.tolist(), "frames": self.frames,
                "wall_s": self.wall_s, "best": self.best, "info": self.info}
