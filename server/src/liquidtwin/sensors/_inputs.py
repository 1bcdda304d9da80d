"""Validation of the per-frame maps and colours that :func:`synth_rgb` takes (private)."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ._common import SensorInputError, check_image_shape


def check_maps(thickness, mask, labels):
    """(thickness, mask, labels as intp) after shape, dtype and range checks."""
    t, m, lab = np.asarray(thickness), np.asarray(mask), np.asarray(labels)
    if m.dtype != np.bool_ or m.ndim != 2:
        raise SensorInputError(f"liquid_mask must be a bool (H, W) array, got {m.dtype} {m.shape}")
    if m.shape[0] < 4 or m.shape[1] < 4:
        raise SensorInputError(f"images must be at least 4×4 px, got {m.shape}")
    if t.dtype == np.bool_ or t.dtype.kind not in "fiu":
        raise SensorInputError(f"liquid_thickness must be a real (H, W) array, got dtype {t.dtype}")
    if lab.dtype == np.bool_ or lab.dtype.kind not in "iu":
        raise SensorInputError(f"labels must be an integer (H, W) array, got dtype {lab.dtype}")
    check_image_shape("liquid_thickness", t, m.shape)
    check_image_shape("labels", lab, m.shape)
    if not np.isfinite(t).all() or (t < 0).any():
        raise SensorInputError("liquid_thickness must be finite and ≥ 0")
    if lab.min() < 0 or lab.max() >= 65536:
        raise SensorInputError("labels must lie in [0, 65535] (0 = background)")
    return t, m, lab.astype(np.intp, copy=False)


def color_table(colors, labels: np.ndarray) -> np.ndarray:
    """(max_label + 1, 3) float32 albedo table; row 0 (background) unused."""
    top = int(labels.max())
    if isinstance(colors, Mapping):
        keys = list(colors)
        rows = [colors[k] for k in keys]
        if any(isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1 for k in keys):
            raise SensorInputError(f"object_colors keys must be labels ≥ 1, got {keys}")
    else:
        rows = colors
        keys = None
    arr = np.asarray(rows)
    if arr.size == 0:
        arr = arr.reshape(0, 3)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.dtype == np.bool_ or arr.dtype.kind not in "fiu":
        raise SensorInputError(f"object_colors must be RGB triples, (K, 3), got shape {arr.shape}")
    if arr.dtype.kind == "f":
        if not np.isfinite(arr).all() or (arr < 0).any() or (arr > 1).any():
            raise SensorInputError(
                "float object_colors must lie in [0, 1] (use integers for 0–255)")
        arr = arr.astype(np.float32)
    else:
        if (arr < 0).any() or (arr > 255).any():
            raise SensorInputError("integer object_colors must lie in 0–255")
        arr = arr.astype(np.float32) / 255.0
    idx = [int(k) for k in keys] if keys is not None else list(range(1, len(arr) + 1))
    table = np.zeros((max([top] + idx) + 1, 3), np.float32)
    have = np.zeros(len(table), bool)
    table[idx], have[idx] = arr, True
    have[0] = True
    if not have.all():       # gaps in a mapping: are any of them used?
        used = np.bincount(labels.ravel(), minlength=len(table)) > 0
        missing = np.flatnonzero(used & ~have).tolist()
    else:
        missing = []
    if missing:
        raise SensorInputError(f"object_colors has no colour for labels {missing}")
    return table
