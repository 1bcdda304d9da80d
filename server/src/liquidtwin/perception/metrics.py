"""Precision–recall with slack (thesis §4.5.1) and its area under the curve.

With slack s px, a pixel predicted liquid (score ≥ τ) is a true positive when a true
liquid pixel lies within s px of it, and a true liquid pixel is recalled when a predicted
pixel lies within s px of it; "within s px" is the (2s+1)×(2s+1) square (Chebyshev
distance ≤ s), so slack 0 is plain pixel-wise precision and recall.

Both are computed for every threshold at once: precision from the score histogram of
pixels near the truth vs all pixels; recall from the histogram of, at each true pixel, the
highest score in its square neighbourhood (a grey dilation) — exact, no threshold loop.
"""

from __future__ import annotations

import cv2
import numpy as np

BINS = 1000


def _square(s: int) -> np.ndarray:
    return np.ones((2 * s + 1, 2 * s + 1), np.uint8)


def _stack(a, name: str, dtype) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3:
        raise ValueError(f"{name} must be (H, W) or (T, H, W), got shape {a.shape}")
    return a.astype(dtype, copy=False)


def pr_curve(scores, truth, slack: int = 0, bins: int = BINS):
    """(precision, recall, thresholds), each (bins,), thresholds ascending in [0, 1).

    scores: (T, H, W) or (H, W) float in [0, 1], higher = more likely liquid.
    truth:  same shape, bool liquid labels.  slack: px, ≥ 0.
    A threshold with no predicted pixel has precision 1 (nothing claimed, nothing wrong).
    """
    p = np.clip(_stack(scores, "scores", np.float32), 0.0, 1.0)
    y = _stack(truth, "truth", bool)
    if p.shape != y.shape:
        raise ValueError(f"scores {p.shape} and truth {y.shape} differ in shape")
    if not np.isfinite(p).all():
        raise ValueError("scores contain NaN or inf")
    s = int(slack)
    if s < 0:
        raise ValueError(f"slack must be ≥ 0 px, got {slack}")
    k = _square(s)
    near = np.stack([cv2.dilate(f.astype(np.uint8), k) for f in y]).astype(bool) if s else y
    best = np.stack([cv2.dilate(f, k) for f in p]) if s else p
    edges = np.linspace(0.0, 1.0, bins + 1)
    idx = np.minimum((p * bins).astype(np.int64), bins - 1)        # bin of each score
    ge = lambda counts: np.cumsum(counts[::-1])[::-1]               # count with score ≥ edge
    claimed = ge(np.bincount(idx.ravel(), minlength=bins))
    right = ge(np.bincount(idx[near], minlength=bins))
    n_true = int(y.sum())
    best_idx = np.minimum((best[y] * bins).astype(np.int64), bins - 1)
    recalled = ge(np.bincount(best_idx, minlength=bins))
    precision = np.where(claimed > 0, right / np.maximum(claimed, 1), 1.0)
    recall = recalled / n_true if n_true else np.zeros(bins)
    return precision, recall, edges[:-1]


def pr_auc(precision, recall) -> float:
    """Area under a PR curve: trapezoids over recall ascending, from recall 0 at the
    curve's highest-threshold precision."""
    r = np.asarray(recall, float)[::-1]
    p = np.asarray(precision, float)[::-1]
    r = np.concatenate([[0.0], r])
    p = np.concatenate([[p[0]], p])
    return float(np.sum(np.diff(r) * 0.5 * (p[1:] + p[:-1])))


def auc(scores, truth, slack: int = 0) -> float:
    """Area under the PR curve with ``slack`` px."""
    return pr_auc(*pr_curve(scores, truth, slack)[:2])
