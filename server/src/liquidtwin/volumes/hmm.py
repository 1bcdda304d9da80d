"""Histogram filter (HMM) over the volume in a target container (SPEC §5, thesis 5.1.3).

The hidden state is the bin index k of the volume (bins: (K,) ml, increasing). The belief
is kept as log probabilities (K,).

- Observation model: over the blocks that see the container interior, an observed liquid
  block has probability P(obs | expected liquid) = 0.9 and P(obs | expected dry) = 0.2
  (and the complements for a dry block), independently per block; the log likelihood of
  each bin is the sum over those blocks (:func:`log_likelihood`).
- Transition: T[i, j] = P(v_t = bin j | v_{t−1} = bin i), rows sum to 1.
  :func:`learn_transition` counts bin changes in true volume series plus a small prior.
  :func:`default_transition` is the shipped default: a band that keeps the bin (0.5) or
  moves up one or two bins (0.3, 0.1) or down one (0.1) per step — a target container mostly
  fills, and small losses (splashes, the estimate's own jitter) must stay possible — with a
  floor of 1e-6 on every other entry so that the filter recovers from a wrong belief.
- :class:`VolumeFilter` ``predict`` / ``update`` are pure functions of the belief;
  ``median`` reports the posterior median, ml.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

P_LIQUID_IF_LIQUID = 0.9
P_LIQUID_IF_DRY = 0.2


def log_likelihood(expected_liquid: np.ndarray, interior: np.ndarray, observed: np.ndarray,
                   p_hit: float = P_LIQUID_IF_LIQUID, p_false: float = P_LIQUID_IF_DRY,
                   fractions=None) -> np.ndarray:
    """(K,) log P(observed mask | volume bin k).

    Args:
      expected_liquid: (K, h, w) bool expected masks. interior: (h, w) bool scored blocks.
      observed: (h, w) bool observed liquid mask on the same grid.
      p_hit: P(observed liquid | expected liquid). p_false: P(observed liquid | expected dry).
      fractions: (K,) optional share f_k ≤ 1 of mask k the liquid covers at an unknown place
        (a pool thinner than it can spread, :class:`~liquidtwin.volumes.LevelTable`): n_k =
        round(f_k · |mask k|) expected blocks, placed where they best explain the observation
        (on observed liquid inside mask k first) — the place is maximised out.
    """
    e = np.asarray(expected_liquid, bool)
    interior, observed = np.asarray(interior, bool), np.asarray(observed, bool)
    if e.ndim != 3 or interior.shape != e.shape[1:] or observed.shape != e.shape[1:]:
        raise ValueError(f"expected (K, h, w), interior and observed (h, w) must agree, got "
                         f"{e.shape}, {interior.shape}, {observed.shape}")
    if not (0 < p_hit < 1 and 0 < p_false < 1):
        raise ValueError(f"pixel probabilities must lie in (0, 1), got {p_hit}, {p_false}")
    ei = e[:, interior]                                  # (K, P)
    oi = observed[interior]                              # (P,)
    hit = (ei & oi).sum(1)
    n_exp = ei.sum(1)
    if fractions is not None:
        f = np.asarray(fractions, float).reshape(-1)
        if f.shape != (len(e),) or not ((f >= 0) & (f <= 1)).all():
            raise ValueError(f"fractions must be ({len(e)},) values in [0, 1]")
        n_exp = np.rint(f * n_exp).astype(np.int64)
    n11 = np.minimum(hit, n_exp)
    n01 = n_exp - n11
    n10 = oi.sum() - n11
    n00 = len(oi) - n11 - n01 - n10
    return (n11 * np.log(p_hit) + n01 * np.log1p(-p_hit)
            + n10 * np.log(p_false) + n00 * np.log1p(-p_false)).astype(float)


def _check_bins(bins) -> np.ndarray:
    bins = np.asarray(bins, float).reshape(-1)
    if len(bins) < 2 or not np.isfinite(bins).all() or (np.diff(bins) <= 0).any():
        raise ValueError("bins must be at least 2 finite, strictly increasing volumes in ml")
    return bins


def _normalise_rows(T: np.ndarray) -> np.ndarray:
    return T / T.sum(1, keepdims=True)


def default_transition(n_bins: int, floor: float = 1e-6) -> np.ndarray:
    """(K, K) banded default transition (module doc): stay 0.5, +1 0.3, +2 0.1, −1 0.1."""
    if n_bins < 2:
        raise ValueError(f"need at least 2 bins, got {n_bins}")
    T = np.full((n_bins, n_bins), float(floor))
    for step, p in ((0, 0.5), (1, 0.3), (2, 0.1), (-1, 0.1)):
        i = np.arange(max(0, -step), min(n_bins, n_bins - step))
        T[i, i + step] += p
    return _normalise_rows(T)


def learn_transition(volume_series_list, bins, prior: float = 0.01, pooled: float = 0.0) -> np.ndarray:
    """(K, K) transition estimated from true volume series.

    Args:
      volume_series_list: iterable of (T_i,) volume series, ml, sampled at the filter's rate.
      bins: (K,) bin volumes, ml; each volume goes to its nearest bin.
      prior: pseudo-count added to every entry (rows never seen become uniform).
      pooled: pseudo-counts per row spread like the bin changes j − i of all rows together
        (a stationary kernel): shrinks rows seen a few times towards the common behaviour.
    """
    bins = _check_bins(bins)
    if not prior > 0:
        raise ValueError(f"prior must be > 0, got {prior}")
    counts = np.full((len(bins), len(bins)), float(prior))
    edges = 0.5 * (bins[1:] + bins[:-1])
    for series in volume_series_list:
        s = np.asarray(series, float).reshape(-1)
        if not np.isfinite(s).all():
            raise ValueError("volume series contain NaN or inf")
        k = np.searchsorted(edges, s)
        np.add.at(counts, (k[:-1], k[1:]), 1.0)
    if pooled > 0:
        n = len(bins)
        i, j = np.indices(counts.shape)
        kernel = np.bincount((j - i + n - 1).ravel(), weights=(counts - prior).ravel(), minlength=2 * n - 1)
        kernel = (kernel + prior) / (kernel + prior).sum()
        counts += pooled * _normalise_rows(kernel[j - i + n - 1])
    return _normalise_rows(counts)


@dataclass(frozen=True, eq=False)
class VolumeFilter:
    """Histogram filter over volume bins.

    Attributes:
      bins: (K,) bin volumes, ml, increasing.
      transition: (K, K) row-stochastic P(next bin j | bin i).
    """

    bins: np.ndarray
    transition: np.ndarray

    def __post_init__(self):
        bins = _check_bins(self.bins)
        T = np.asarray(self.transition, float)
        if T.shape != (len(bins), len(bins)) or not np.isfinite(T).all() or (T < 0).any():
            raise ValueError(f"transition must be a ({len(bins)}, {len(bins)}) non-negative matrix, "
                             f"got shape {T.shape}")
        if not np.allclose(T.sum(1), 1.0, atol=1e-6):
            raise ValueError("transition rows must sum to 1 (P(next bin | bin))")
        object.__setattr__(self, "bins", bins)
        object.__setattr__(self, "transition", T)

    def initial(self, prior=None) -> np.ndarray:
        """(K,) log belief: uniform, or the given (K,) non-negative prior normalised."""
        p = np.ones(len(self.bins)) if prior is None else np.asarray(prior, float).reshape(-1)
        if p.shape != self.bins.shape or (p < 0).any() or not p.sum() > 0:
            raise ValueError(f"prior must be ({len(self.bins)},) non-negative, not all zero")
        with np.errstate(divide="ignore"):
            return np.log(p / p.sum())

    def predict(self, log_belief: np.ndarray) -> np.ndarray:
        """(K,) log belief after one transition step."""
        m = log_belief.max()
        p = np.exp(log_belief - m) @ self.transition
        with np.errstate(divide="ignore"):
            return np.log(p / p.sum())

    def update(self, log_belief: np.ndarray, log_lik: np.ndarray) -> np.ndarray:
        """(K,) normalised log posterior given the (K,) log likelihood of an observation."""
        log_lik = np.asarray(log_lik, float).reshape(-1)
        if log_lik.shape != self.bins.shape or np.isnan(log_lik).any():
            raise ValueError(f"log likelihood must be ({len(self.bins)},) without NaN")
        post = log_belief + log_lik
        m = post.max()
        if not np.isfinite(m):
            raise ValueError("the observation rules out every volume bin")
        return post - (m + np.log(np.exp(post - m).sum()))

    def probabilities(self, log_belief: np.ndarray) -> np.ndarray:
        """(K,) probabilities of the bins."""
        p = np.exp(log_belief - log_belief.max())
        return p / p.sum()

    def median(self, log_belief: np.ndarray) -> float:
        """Posterior median, ml: the first bin where the cumulative probability reaches ½."""
        c = np.cumsum(self.probabilities(log_belief))
        return float(self.bins[min(int(np.searchsorted(c, 0.5 - 1e-12)), len(self.bins) - 1)])
