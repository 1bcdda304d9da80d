"""Overlay of model and observed liquid in thesis Fig. 8.10's colours, with its pixel counts.

Colours (docs/service.md): observed liquid only blue (0, 0, 255), model liquid only green
(0, 255, 0), both yellow (255, 255, 0), neither dark grey :data:`BACKGROUND_RGB`.
IOU = |observed ∩ model| / |observed ∪ model| (1.0 when both are empty, as
:func:`liquidtwin.camera.iou`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

OBSERVED_RGB = (0, 0, 255)
MODEL_RGB = (0, 255, 0)
OVERLAP_RGB = (255, 255, 0)
BACKGROUND_RGB = (48, 48, 48)


def pack_rgb(rgb) -> int:
    """(r, g, b) 0..255 → 0xRRGGBB (``OverlayInfo`` colour fields)."""
    r, g, b = (int(c) for c in rgb)
    return (r << 16) | (g << 8) | b


@dataclass(frozen=True)
class Overlay:
    """image: (H, W, 3) uint8 RGB; observed_px = |observed|, model_px = |model|,
    overlap_px = |observed ∩ model| (totals, overlap included in both); iou in [0, 1]."""

    image: np.ndarray
    observed_px: int
    model_px: int
    overlap_px: int
    iou: float


def make_overlay(observed: np.ndarray, model: np.ndarray) -> Overlay:
    """Overlay of two (H, W) bool masks: ``observed`` (camera) and ``model`` (particles)."""
    observed, model = np.asarray(observed), np.asarray(model)
    if observed.dtype != bool or model.dtype != bool:
        raise ValueError(f"overlay needs bool masks, got {observed.dtype} and {model.dtype}")
    if observed.ndim != 2 or observed.shape != model.shape:
        raise ValueError(f"overlay needs two (H, W) masks of one size, got {observed.shape} and {model.shape}")
    both = observed & model
    image = np.empty(observed.shape + (3,), np.uint8)
    image[...] = BACKGROUND_RGB
    image[observed & ~model] = OBSERVED_RGB
    image[model & ~observed] = MODEL_RGB
    image[both] = OVERLAP_RGB
    n_obs, n_model, n_both = int(observed.sum()), int(model.sum()), int(both.sum())
    union = n_obs + n_model - n_both
    return Overlay(image, n_obs, n_model, n_both, 1.0 if union == 0 else n_both / union)
