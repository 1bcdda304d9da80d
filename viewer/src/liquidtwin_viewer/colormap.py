"""Speed colouring of particles, its legend, and pose conversions for viser."""

from __future__ import annotations

import numpy as np

#: Colour stops of the speed ramp, RGB 0..255, evenly spaced from slow (0) to fast (1):
#: deep blue, blue, cyan, yellow, red.
RAMP = np.array([[25, 35, 110], [40, 110, 230], [60, 200, 215], [245, 215, 60],
                 [215, 45, 35]], np.float64)

_MIN_RANGE = 0.05  # m/s: a still liquid is not stretched over the whole ramp


def speed_colors(speed: np.ndarray, vmax: float) -> np.ndarray:
    """Colours of particles by speed.

    Args:
        speed: (N,) speeds, m/s; NaN draws as the slowest colour.
        vmax: speed at the top of the ramp, m/s (> 0); faster particles clip to it.

    Returns:
        (N, 3) uint8 RGB.
    """
    if not vmax > 0:
        raise ValueError(f"vmax must be a positive speed in m/s, got {vmax}")
    s = np.nan_to_num(np.asarray(speed, np.float64), nan=0.0) / vmax
    return ramp(np.clip(s, 0.0, 1.0))


def ramp(u: np.ndarray) -> np.ndarray:
    """(…) values in [0, 1] -> (…, 3) uint8 colours of the ramp (piecewise linear)."""
    x = np.asarray(u, np.float64) * (len(RAMP) - 1)
    i = np.clip(np.floor(x).astype(np.int64), 0, len(RAMP) - 2)
    f = (x - i)[..., None]
    return np.rint(RAMP[i] * (1 - f) + RAMP[i + 1] * f).astype(np.uint8)


def legend_image(width: int = 256, height: int = 16) -> np.ndarray:
    """(height, width, 3) uint8 picture of the ramp, slow on the left."""
    return np.repeat(ramp(np.linspace(0.0, 1.0, width))[None], height, axis=0)


def auto_vmax(speed: np.ndarray, previous: float | None = None, *, decay: float = 0.9) -> float:
    """Top of the colour range for a frame: the 99th percentile speed (at least 0.05 m/s),
    rising at once and falling smoothly (``decay`` per frame) to avoid flicker, m/s."""
    finite = np.asarray(speed)[np.isfinite(speed)]
    target = max(float(np.percentile(finite, 99)) if finite.size else 0.0, _MIN_RANGE)
    if previous is None or target >= previous:
        return target
    return max(target, decay * previous + (1 - decay) * target)


def pose_to_viser(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A (7,) pose (tx, ty, tz, qx, qy, qz, qw) as viser's (position (3,), wxyz (4,))."""
    pose = np.asarray(pose, np.float64)
    return pose[:3].copy(), np.array([pose[6], pose[3], pose[4], pose[5]])
