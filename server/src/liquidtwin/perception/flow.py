"""Dense optical flow as a network input (thesis §4.4.2) and grey conversion.

Farnebäck flow from the previous frame to the current one with the thesis's parameters
(3 pyramid levels, scale 0.5, window 15, 3 iterations, neighbourhood 5, σ 1.2, no other
filtering), encoded per pixel as three planes: sin and cos of the flow's angle, and its
magnitude divided by ``FLOW_SCALE_PX`` (so typical liquid motion lands in ~[0, 1]; not
clipped). Where the flow is exactly zero the angle is 0 (sin 0, cos 1).
"""

from __future__ import annotations

import cv2
import numpy as np


class PerceptionInputError(ValueError):
    """An image or flow field given to perception has the wrong shape, dtype or values."""


FARNEBACK = dict(pyr_scale=0.5, levels=3, winsize=15, iterations=3, poly_n=5, poly_sigma=1.2, flags=0)
FLOW_SCALE_PX = 4.0   # magnitude plane = |flow| px / this; liquid at 320×240 moves ~1–8 px per frame


def check_rgb(image, name: str = "image") -> np.ndarray:
    """(H, W, 3) uint8 RGB → the same array; clear error otherwise."""
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3:
        raise PerceptionInputError(f"{name} must be an (H, W, 3) RGB image, got shape {a.shape}")
    if a.dtype != np.uint8:
        raise PerceptionInputError(f"{name} must be uint8 (0–255), got {a.dtype}")
    if a.shape[0] < 8 or a.shape[1] < 8:
        raise PerceptionInputError(f"{name} is {a.shape[1]}×{a.shape[0]} px; at least 8×8 needed")
    return a


def grey_u8(image) -> np.ndarray:
    """(H, W, 3) uint8 RGB → (H, W) uint8 luma (ITU-R 601 weights, OpenCV's)."""
    return cv2.cvtColor(check_rgb(image), cv2.COLOR_RGB2GRAY)


def farneback(prev_grey: np.ndarray, grey: np.ndarray) -> np.ndarray:
    """(H, W, 2) float32 flow in px, prev → current, from two (H, W) uint8 grey frames."""
    for name, g in (("prev_grey", prev_grey), ("grey", grey)):
        if not isinstance(g, np.ndarray) or g.ndim != 2 or g.dtype != np.uint8:
            raise PerceptionInputError(f"{name} must be an (H, W) uint8 grey image, got "
                                       f"{getattr(g, 'shape', None)} {getattr(g, 'dtype', type(g).__name__)}")
    if prev_grey.shape != grey.shape:
        raise PerceptionInputError(f"flow frames differ in size: {prev_grey.shape} vs {grey.shape}")
    return cv2.calcOpticalFlowFarneback(prev_grey, grey, None, **FARNEBACK)


def encode_flow(flow: np.ndarray) -> np.ndarray:
    """(H, W, 2) flow in px → (3, H, W) float32 planes: sin θ, cos θ, |flow| / FLOW_SCALE_PX."""
    f = np.asarray(flow, np.float32)
    if f.ndim != 3 or f.shape[2] != 2:
        raise PerceptionInputError(f"flow must be (H, W, 2), got {f.shape}")
    mag = np.hypot(f[..., 0], f[..., 1])
    safe = np.where(mag > 0, mag, 1.0)
    sin = np.where(mag > 0, f[..., 1] / safe, 0.0)
    cos = np.where(mag > 0, f[..., 0] / safe, 1.0)
    return np.stack([sin, cos, mag / FLOW_SCALE_PX]).astype(np.float32)


def flow_planes(prev_grey: np.ndarray | None, grey: np.ndarray) -> np.ndarray:
    """(3, H, W) encoded flow into ``grey``; the first frame of a stream (``prev_grey`` None)
    gets zero flow (sin 0, cos 1, magnitude 0) — a live stream has no next frame to borrow."""
    if prev_grey is None:
        return encode_flow(np.zeros(grey.shape + (2,), np.float32))
    return encode_flow(farneback(prev_grey, grey))
