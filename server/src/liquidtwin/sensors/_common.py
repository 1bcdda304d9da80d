"""Shared checks and random fields for the sensor models (private)."""

from __future__ import annotations

import math
from statistics import NormalDist

import cv2
import numpy as np


class SensorInputError(ValueError):
    """A sensor model got an array or parameter it cannot use (shape, dtype, NaN, range)."""


def check_generator(rng) -> np.random.Generator:
    """Return ``rng`` if it is a numpy Generator; the models never touch global RNG state."""
    if not isinstance(rng, np.random.Generator):
        raise SensorInputError(
            f"rng must be a numpy.random.Generator (e.g. numpy.random.default_rng(seed)), "
            f"got {type(rng).__name__}")
    return rng


def check_number(name: str, value, lo: float, hi: float) -> float:
    """``value`` as a float in [lo, hi], or a SensorInputError naming the parameter."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SensorInputError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or not lo <= v <= hi:
        raise SensorInputError(f"{name} must be within [{lo}, {hi}], got {value!r}")
    return v


def check_image_shape(name: str, arr: np.ndarray, shape: tuple) -> None:
    if arr.shape != shape:
        raise SensorInputError(f"{name} must have shape {shape}, got {arr.shape}")


def smooth_noise(rng: np.random.Generator, height: int, width: int, scale_px: float) -> np.ndarray:
    """Zero-mean, unit-std random field (height, width) float32, correlated over ~scale_px px.

    Gaussian knots every ``scale_px`` px, bicubically interpolated; ``scale_px`` < 1.5 gives
    white noise.
    """
    if scale_px < 1.5:
        return rng.standard_normal((height, width), dtype=np.float32)
    gh = max(2, int(math.ceil(height / scale_px)) + 1)
    gw = max(2, int(math.ceil(width / scale_px)) + 1)
    knots = rng.standard_normal((gh, gw), dtype=np.float32)
    f = cv2.resize(knots, (width, height), interpolation=cv2.INTER_CUBIC)
    sub = f[::3, ::3]                 # mean/std from a subsample: same field, 9x cheaper
    f -= sub.mean()
    s = float(sub.std())
    if s > 0:
        f *= 1.0 / s
    return f


def _gauss_lut() -> np.ndarray:
    # 256 equiprobable quantiles of N(0, 1): one random byte becomes one Gaussian sample.
    nd = NormalDist()
    lut = np.array([nd.inv_cdf((i + 0.5) / 256.0) for i in range(256)], np.float32)
    lut /= lut.std()
    lut.setflags(write=False)
    return lut


GAUSS_LUT = _gauss_lut()


def fast_gaussian(rng: np.random.Generator, shape: tuple) -> np.ndarray:
    """Unit-variance Gaussian samples quantised to 256 levels, (shape) float32.

    One random byte per sample through an inverse-CDF table: ~10x faster than
    ``standard_normal`` and good enough for sensor noise and textures.
    """
    n = int(np.prod(shape))
    words = rng.integers(0, 2**64 - 1, (n + 7) // 8, dtype=np.uint64, endpoint=True)
    idx = words.view(np.uint8)[:n].reshape(1, n)
    return cv2.LUT(idx, GAUSS_LUT.reshape(1, 256)).reshape(shape)
