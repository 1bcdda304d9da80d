"""The optical-flow baseline of thesis §4.5.3 (after Yamaguchi and Atkeson): liquid is what
moves, filtered morphologically and in time.

Steps on each frame's Farnebäck flow magnitude image (kernel sizes the thesis's, for
400×300; ours are the same at 320×240):
1. erode 3×3, 2. dilate 3×3 (an opening: drops isolated moving pixels),
3. temporal OR (here max) over a window of 5 frames,
4. dilate 7×7, 5. erode 11×11, 6. dilate 13×13, 7. vertical 12×1 box filter (mean),
8. the result of 7 masks the result of 3 (where it exceeds ``MOVING_PX``, a
magnitude: Farnebäck never returns exact zeros, so a > 0 mask would keep everything), 9. the 12×1 filter again, 10. scaled to [0, 1].
The thesis's depth mask (background motion > 1 m away) has no counterpart in a single RGB
camera, so it is left out. The output is a per-pixel score (PR curves sweep it) — the
thesis approximates a probability by the flow magnitude the same way.

The temporal window is centred (frames t−2 … t+2), as an offline filter; ``causal=True``
uses t−4 … t for a live stream.
"""

from __future__ import annotations

import cv2
import numpy as np

from .flow import check_rgb, farneback, grey_u8

MOVING_PX = 0.5       # flow magnitude (px per frame) that counts as motion in step 8


def _k(n: int) -> np.ndarray:
    return np.ones((n, n), np.uint8)


def flow_magnitudes(frames) -> np.ndarray:
    """(T, H, W) float32 flow magnitudes in px; the first frame uses the next one (thesis)."""
    greys = [grey_u8(check_rgb(f, "frame")) for f in frames]
    if len(greys) < 2:
        raise ValueError("the flow baseline needs at least 2 frames")
    mags = []
    for t in range(len(greys)):
        a, b = (greys[1], greys[0]) if t == 0 else (greys[t - 1], greys[t])
        f = farneback(a, b)
        mags.append(np.hypot(f[..., 0], f[..., 1]))
    return np.stack(mags).astype(np.float32)


def baseline_scores(frames, *, causal: bool = False, window: int = 5) -> np.ndarray:
    """(T, H, W) float32 liquid scores in [0, 1] for a sequence of (H, W, 3) uint8 frames."""
    mag = flow_magnitudes(frames)
    opened = np.stack([cv2.dilate(cv2.erode(m, _k(3)), _k(3)) for m in mag])
    t_n = len(opened)
    temporal = np.empty_like(opened)
    for t in range(t_n):
        lo, hi = (t - window + 1, t + 1) if causal else (t - window // 2, t + window // 2 + 1)
        temporal[t] = opened[max(lo, 0):min(hi, t_n)].max(axis=0)
    out = np.empty_like(temporal)
    for t in range(t_n):
        region = cv2.dilate(cv2.erode(cv2.dilate(temporal[t], _k(7)), _k(11)), _k(13))
        region = cv2.blur(region, (1, 12))
        out[t] = cv2.blur(np.where(region > MOVING_PX, temporal[t], 0.0).astype(np.float32), (1, 12))
    top = float(out.max())
    return out / top if top > 0 else out
