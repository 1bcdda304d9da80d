"""Histogram filter (HMM) over the volume in a target container (SPEC §5, thesis 5.1.3).

The hidden state is the bin index k of the volume (bins: (K,) ml, increasing). The belief
is kept as log probabilities (K,).

- Observation model: over the blocks that see the container interior, an observed liquid
  block has probability P(obs | expected liquid) = 0.9 and P(obs | expected dry) = 0.2
  (and the complements for a dry block), independently per block; the log likelihood of
  each bin is the sum over those blocks, with the liquid at its likeliest place: a shallow
  pool anywhere on the floor; optionally a sloshing surface a little off the level plane's
  place (:func:`log_likelihood`).
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


#: How far a volume's expected mask may move to meet a sloshing surface, as a share of the
#: scored blocks' extent per image axis (:func:`log_likelihood` ``shift``). Off (0: SPEC's flat
#: surface at the level holding v): 0.15 cut the target's RMSE on 18 full training pours but
#: not on the benchmark's (README "Volumes", ``bench/volume_surface_offset.py --shifts``).
SHIFT_SHARE = 0.0
#: A moved mask must keep this share of its blocks on the scored blocks, so that no move hides
#: liquid behind the walls.
CONTAINED = 0.9


def _placements(templates: np.ndarray, images: list, reach: tuple) -> list:
    """Correlations C[k, dy, dx] = Σ templates[k, y, x] · image[y + dy, x + dx] of every (K, h,
    w) template with every (h, w) image of ``images``, for |dy| ≤ reach[0], |dx| ≤ reach[1]:
    exact integer counts of bool arrays (by FFT, zero-padded so nothing wraps)."""
    K, h, w = templates.shape
    ry, rx = reach
    if ry == rx == 0:                                      # one place: plain counts
        return [(templates & img[None]).sum((1, 2))[:, None, None] for img in images]
    shape = (h + ry + 1, w + rx + 1)
    ft = np.conj(np.fft.rfft2(templates.astype(np.float64), s=shape))
    out = []
    for img in images:
        c = np.fft.irfft2(ft * np.fft.rfft2(img.astype(np.float64), s=shape)[None], s=shape)
        c = np.rint(c).astype(np.int64)
        rows = np.r_[shape[0] - ry:shape[0], 0:ry + 1]            # dy = −ry … ry
        cols = np.r_[shape[1] - rx:shape[1], 0:rx + 1]
        out.append(c[:, rows][:, :, cols])
    return out


def log_likelihood(expected_liquid: np.ndarray, interior: np.ndarray, observed: np.ndarray,
                   p_hit: float = P_LIQUID_IF_LIQUID, p_false: float = P_LIQUID_IF_DRY,
                   fractions=None, shift: float = SHIFT_SHARE) -> np.ndarray:
    """(K,) log P(observed mask | volume bin k), the liquid's place maximised out.

    Args:
      expected_liquid: (K, h, w) bool expected masks. interior: (h, w) bool scored blocks.
      observed: (h, w) bool observed liquid mask on the same grid.
      p_hit: P(observed liquid | expected liquid). p_false: P(observed liquid | expected dry).
      fractions: (K,) optional share f_k ≤ 1 of mask k the liquid covers at an unknown place
        (a pool thinner than it can spread, :class:`~liquidtwin.volumes.LevelTable`): n_k =
        round(f_k · |mask k|) expected blocks, placed where they best explain the observation
        (on observed liquid inside mask k first) — the place is maximised out.
      shift: a whole mask (f_k = 1) may lie up to this share of the scored blocks' extent
        away along each image axis, keeping :data:`CONTAINED` of it on the scored blocks (a
        sloshing surface), the likeliest move counting as a pool's place does. 0 (the default,
        :data:`SHIFT_SHARE`): only where the level plane puts it.

    Why the moves: a sloshing surface can miss the level plane's mask by a quarter of its
    blocks, each costing log(0.1/0.9), while a pool, free to pick its blocks, misses none. A
    90 % cup dumped into the full-size pan (327 ml, a training pour) read as a pool of 140 ml.
    """
    e = np.asarray(expected_liquid, bool)
    interior, observed = np.asarray(interior, bool), np.asarray(observed, bool)
    if e.ndim != 3 or interior.shape != e.shape[1:] or observed.shape != e.shape[1:]:
        raise ValueError(f"expected (K, h, w), interior and observed (h, w) must agree, got "
                         f"{e.shape}, {interior.shape}, {observed.shape}")
    if not (0 < p_hit < 1 and 0 < p_false < 1):
        raise ValueError(f"pixel probabilities must lie in (0, 1), got {p_hit}, {p_false}")
    if not (np.isfinite(shift) and 0 <= shift <= 1):
        raise ValueError(f"shift must be a share in [0, 1], got {shift}")
    K = len(e)
    f = np.ones(K)
    if fractions is not None:
        f = np.asarray(fractions, float).reshape(-1)
        if f.shape != (K,) or not ((f >= 0) & (f <= 1)).all():
            raise ValueError(f"fractions must be ({K},) values in [0, 1]")
    P = int(interior.sum())
    obs = observed & interior
    n_obs = int(obs.sum())
    lp = (np.log(p_hit), np.log1p(-p_hit), np.log(p_false), np.log1p(-p_false))

    def score(n11, n_exp):
        n01, n10 = n_exp - n11, n_obs - n11
        return n11 * lp[0] + n01 * lp[1] + n10 * lp[2] + (P - n11 - n01 - n10) * lp[3]

    out = np.full(K, float(score(0, 0)))                   # a bin whose mask is empty here: nothing expected
    ei = e[:, interior]
    n_mask = ei.sum(1)
    pool = (f < 1) & (n_mask > 0)
    if pool.any():
        # a pool's n_k blocks lie anywhere on its mask: on observed liquid first
        n_exp = np.rint(f[pool] * n_mask[pool]).astype(np.int64)
        out[pool] = score(np.minimum((ei[pool] & obs[interior]).sum(1), n_exp), n_exp)
    whole = np.nonzero((f >= 1) & (n_mask > 0))[0]
    if len(whole) == 0:
        return out
    ys, xs = np.nonzero(interior)                          # work on the scored blocks' box
    box = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    I, O = interior[box], obs[box]
    E = e[(slice(None),) + box][whole] & I[None]
    h, w = I.shape
    n_exp, n11 = _placements(E, [I, O], (int(shift * (h - 1)), int(shift * (w - 1))))
    ll = np.where(n_exp >= CONTAINED * n_mask[whole][:, None, None], score(n11, n_exp), -np.inf)
    out[whole] = ll.reshape(len(whole), -1).max(1)        # the likeliest move, as a pool's place
    return out


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
