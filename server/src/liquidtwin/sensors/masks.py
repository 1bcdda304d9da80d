"""Realistic errors of binary liquid masks from a thermal camera or a segmentation network.

Three error processes, applied to the true mask in this order:

1. **Ragged edges** — the boundary is moved in and out by a smooth random signed offset
   (std ``ragged_px`` px, clipped at 3 std): a noise-warped erosion/dilation. Only pixels
   within ``3·ragged_px + 1`` px of the true boundary can change.
2. **Misses** — exactly ``round(miss · n_liquid)`` true liquid pixels are reported dry:
   ``1 − speck_share`` of them as spatially correlated blobs (the top quantile of a smooth
   random field of correlation length ``blob_px``), the rest as isolated pixels.
3. **False liquid** — exactly ``round(false · n_dry)`` truly dry pixels are reported wet, as
   small blobs (peaks of a field of correlation length ``blob_px``; a few px each) and
   isolated specks in the same split.

Measured against the true mask with ``ragged_px = 0`` the miss and false rates equal the
parameters (up to rounding); ragged edges add a roughly balanced error along the boundary.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import cv2
import numpy as np

from ._common import SensorInputError, check_generator, check_number, smooth_noise


@dataclass(frozen=True)
class MaskNoise:
    """Parameters of :func:`corrupt_mask` (fractions are of pixels, lengths in px).

    miss:        fraction of true liquid pixels reported dry, [0, 0.9]
    false:       fraction of truly dry pixels reported liquid, [0, 0.5]
    ragged_px:   std of the boundary offset, px, [0, 20]
    blob_px:     correlation length of the missed / false blob fields, px, [1, 100]
    speck_share: share of missed / false pixels that are isolated single pixels, [0, 1]
    """

    miss: float = 0.05
    false: float = 0.005
    ragged_px: float = 1.5
    blob_px: float = 6.0
    speck_share: float = 0.2

    NONE: ClassVar["MaskNoise"]

    def __post_init__(self):
        for name, lo, hi in (("miss", 0, 0.9), ("false", 0, 0.5), ("ragged_px", 0, 20),
                             ("blob_px", 1, 100), ("speck_share", 0, 1)):
            value = check_number(f"MaskNoise.{name}", getattr(self, name), lo, hi)
            object.__setattr__(self, name, value)

    @staticmethod
    def sample(rng: np.random.Generator) -> "MaskNoise":
        """Random plausible noise levels (one recording's perception quality)."""
        check_generator(rng)
        u = rng.uniform
        return MaskNoise(miss=u(0.0, 0.15), false=u(0.0, 0.01), ragged_px=u(0.0, 3.0),
                         blob_px=u(2.0, 10.0), speck_share=u(0.0, 0.5))


MaskNoise.NONE = MaskNoise(miss=0.0, false=0.0, ragged_px=0.0)


def corrupt_mask(mask: np.ndarray, rng: np.random.Generator, noise: MaskNoise | None = None, *,
                 miss: float | None = None, false: float | None = None,
                 ragged_px: float | None = None, blob_px: float | None = None,
                 speck_share: float | None = None) -> np.ndarray:
    """A noisy copy of the true liquid mask, as a thermal camera or perception net reports it.

    mask:  (H, W) or (..., H, W) bool, True where liquid is visible.
    rng:   numpy Generator; the only source of randomness (same seed → same output).
    noise: parameters (default ``MaskNoise()``); the keyword arguments override single fields.
    Returns a new bool array of the same shape; frames of a stack get independent noise.
    """
    rng = check_generator(rng)
    if noise is None:
        noise = MaskNoise()
    if not isinstance(noise, MaskNoise):
        raise SensorInputError(f"noise must be a MaskNoise, got {type(noise).__name__}")
    overrides = {k: v for k, v in dict(miss=miss, false=false, ragged_px=ragged_px, blob_px=blob_px,
                                       speck_share=speck_share).items() if v is not None}
    noise = dataclasses.replace(noise, **overrides)
    mask = np.asarray(mask)
    if mask.dtype != np.bool_:
        raise SensorInputError(f"mask must be a bool array (H, W), got dtype {mask.dtype}; "
                               "convert e.g. with mask > 0")
    if mask.ndim < 2 or mask.shape[-1] < 1 or mask.shape[-2] < 1:
        raise SensorInputError(f"mask must be (H, W) or (..., H, W), got shape {mask.shape}")
    out = np.empty_like(mask)
    for idx in np.ndindex(mask.shape[:-2]):
        out[idx] = _corrupt_frame(mask[idx], rng, noise)
    return out


def _corrupt_frame(mask: np.ndarray, rng: np.random.Generator, nz: MaskNoise) -> np.ndarray:
    out = mask.copy()
    if nz.ragged_px > 0 and mask.any():   # nothing beyond 3·ragged_px + 1 of the liquid changes
        y0, y1, x0, x1 = _box(mask, int(np.ceil(3 * nz.ragged_px)) + 2)
        out[y0:y1, x0:x1] = _ragged(mask[y0:y1, x0:x1], rng, nz.ragged_px)
    if nz.miss > 0 and mask.any():
        y0, y1, x0, x1 = _box(mask, 0)
        win = out[y0:y1, x0:x1]
        win[_pick(mask[y0:y1, x0:x1], rng, nz.miss, nz.blob_px, nz.speck_share)] = False
    if nz.false > 0:
        out[_pick(~mask, rng, nz.false, nz.blob_px, nz.speck_share)] = True
    return out


def _box(mask: np.ndarray, margin: int) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1): bounding box of ``mask`` grown by ``margin`` px, clipped to the image.

    Cropping to it is exact for the distance transforms below: the crop holds all liquid, and
    unless it touches the image border it has a dry rim of ≥ 2 px.
    """
    x, y, bw, bh = cv2.boundingRect(mask.view(np.uint8))
    h, w = mask.shape
    return max(0, y - margin), min(h, y + bh + margin), max(0, x - margin), min(w, x + bw + margin)


def _ragged(mask: np.ndarray, rng: np.random.Generator, ragged_px: float) -> np.ndarray:
    """Threshold the signed distance to the boundary after adding a smooth random offset."""
    h, w = mask.shape
    m8 = mask.astype(np.uint8)
    d_in = cv2.distanceTransform(m8, cv2.DIST_L2, cv2.DIST_MASK_5)       # liquid px → nearest dry
    d_out = cv2.distanceTransform(1 - m8, cv2.DIST_L2, cv2.DIST_MASK_5)  # dry px → nearest liquid
    signed = np.where(mask, d_in - 0.5, 0.5 - d_out)  # ±0.5 on the two sides of the boundary
    jitter = 0.8 * smooth_noise(rng, h, w, 2.0)                       # ragged at pixel scale
    jitter += 0.6 * smooth_noise(rng, h, w, 3.0 * max(2.0, ragged_px))  # + a slower wobble
    np.clip(jitter, -3.0, 3.0, out=jitter)
    return signed + ragged_px * jitter > 0


def _pick(region: np.ndarray, rng: np.random.Generator, frac: float, blob_px: float,
          speck_share: float) -> np.ndarray:
    """Bool (H, W): round(frac·|region|) pixels of ``region``, mostly as blobs, some as specks."""
    h, w = region.shape
    field = smooth_noise(rng, h, w, blob_px)
    n_region = int(region.sum())
    n = int(round(frac * n_region))
    n_speck = int(round(speck_share * n))
    n_blob = n - n_speck
    picked = np.zeros_like(region)
    if n_blob > 0:
        vals = field[region]
        thr = np.partition(vals, n_region - n_blob)[n_region - n_blob]
        picked = region & (field >= thr)
    if n_speck > 0:
        free = np.flatnonzero(region & ~picked)
        chosen = rng.choice(free, size=min(n_speck, free.size), replace=False)
        picked.reshape(-1)[chosen] = True
    return picked
