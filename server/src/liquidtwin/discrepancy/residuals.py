"""How far a model's masks are from the observed ones, frame by frame, and where.

Pixel IOU is the contract's metric, but on thin streams it is mostly chaos: two runs of the
same model a few millimetres apart share almost no pixels. Discovery therefore compares
*coarse* masks — 4×4-pixel cells counted as liquid when at least 2 of their 16 pixels are
(isolated specks of mask noise drop out, droplets and streams stay) — by where the liquid is
and how much of it there is:

- ``w1``: the 1-D Wasserstein distances between the row and between the column profiles
  (liquid per image row / column, normalised), in cells, summed; 0 when both hold fewer
  than ``MIN_CELLS`` cells (specks, or liquid hidden in a container), a fixed ``EMPTY_W1``
  when only one does;
- ``mass``: |n_model − n_obs| / (n_model + n_obs + ``MASS_SOFT``), cells (0 when both are
  below ``MIN_CELLS``);
- ``loss`` = w1 / ``W1_SCALE`` + mass, the quantity fitted and compared.

Also per frame: pixel ``iou``, and signed difference maps for the report.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

CELL = 4
CELL_MIN = 2
EMPTY_W1 = 5.0
W1_SCALE = 10.0
MASS_SOFT = 4.0
MIN_CELLS = 5


def coarse(masks: np.ndarray) -> np.ndarray:
    """(F, H, W) bool → (F, H/4, W/4) bool cells holding ≥ 2 liquid pixels (a partial cell at
    the right or bottom edge: ≥ 2 × its share of 16 pixels, as ``avg_pool2d(ceil_mode=True)``
    averages it). Whole cells are counted in bytes (a full-size pour's 241 masks: 4× faster
    than the float pooling, the same cells)."""
    masks = np.asarray(masks)
    f, h, w = masks.shape
    if masks.dtype == np.bool_ and h % CELL == 0 and w % CELL == 0:
        u = np.ascontiguousarray(masks).view(np.uint8).reshape(f, h // CELL, CELL, w)
        rows = u.sum(2, dtype=np.uint8)                       # ≤ 4 per column of a cell
        return rows.reshape(f, h // CELL, w // CELL, CELL).sum(3, dtype=np.uint8) >= CELL_MIN
    t = torch.from_numpy(np.ascontiguousarray(masks, dtype=np.float32))[:, None]
    pooled = F.avg_pool2d(t, CELL, CELL, ceil_mode=True)[:, 0] * (CELL * CELL)
    return (pooled >= CELL_MIN - 1e-6).numpy()


def _w1(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise 1-D Wasserstein distance between histograms a, b (F, L) (normalised here)."""
    na, nb = a.sum(1, keepdims=True), b.sum(1, keepdims=True)
    ca = np.cumsum(a / np.maximum(na, 1e-12), 1)
    cb = np.cumsum(b / np.maximum(nb, 1e-12), 1)
    d = np.abs(ca - cb).sum(1)
    sa, sb = na[:, 0] >= MIN_CELLS, nb[:, 0] >= MIN_CELLS
    one = sa != sb
    none = ~sa & ~sb
    return np.where(one, EMPTY_W1, np.where(none, 0.0, d))


def cell_metrics(cm: np.ndarray, co: np.ndarray) -> dict:
    """Per-frame comparison of coarse model cells ``cm`` with observed cells ``co``, both
    (F, h, w) bool (:func:`coarse`). Returns {"loss", "w1", "mass", "model_cells",
    "obs_cells"}: (F,) float arrays."""
    w1 = _w1(cm.sum(2).astype(float), co.sum(2).astype(float)) + _w1(cm.sum(1).astype(float), co.sum(1).astype(float))
    nm, no = cm.sum((1, 2)).astype(float), co.sum((1, 2)).astype(float)
    mass = np.where((nm < MIN_CELLS) & (no < MIN_CELLS), 0.0, np.abs(nm - no) / (nm + no + MASS_SOFT))
    return {"loss": w1 / W1_SCALE + mass, "w1": w1, "mass": mass, "model_cells": nm, "obs_cells": no}


def pixel_iou(model: np.ndarray, obs: np.ndarray) -> np.ndarray:
    """(F,) IOU of (F, H, W) bool masks; 1 where both are empty."""
    inter = np.array([np.count_nonzero(m & o) for m, o in zip(model, obs)], np.int64)
    union = np.array([np.count_nonzero(m | o) for m, o in zip(model, obs)], np.int64)
    return np.where(union > 0, inter / np.maximum(union, 1), 1.0)


def centroids(cells: np.ndarray) -> np.ndarray:
    """(F, 2) (row, column) centroid of each frame's liquid cells, NaN when empty."""
    n = cells.sum((1, 2)).astype(float)
    r = np.arange(cells.shape[1])[None, :, None]
    c = np.arange(cells.shape[2])[None, None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.stack([(cells * r).sum((1, 2)) / n, (cells * c).sum((1, 2)) / n], 1)


def difference_map(model: np.ndarray, obs: np.ndarray, frames) -> np.ndarray:
    """(H/4, W/4) float: over ``frames``, the share of frames each cell is liquid in the
    observation minus in the model (> 0: the model misses liquid there)."""
    idx = list(frames)
    if not idx:
        return np.zeros(coarse(obs[:1]).shape[1:])
    return coarse(obs[idx]).mean(0) - coarse(model[idx]).mean(0)
