"""Painting rigid objects and transparent liquid into a float RGB frame (private to rgb.py).

Image-space conventions: x right, y down, z towards the camera; a light direction is a unit
vector in that frame pointing from the surface towards the light. Images are float32 colour
planes (3, H, W), RGB in [0, 1] (values may exceed 1 before the camera model clips them):
planar, because numpy broadcasts a (H, W) field over planes ~40x faster than over an
interleaved last axis of 3. Work is confined to the bounding box of the objects / the liquid
plus a margin.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ._common import fast_gaussian

_VIEW = np.array([0.0, 0.0, 1.0], np.float32)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float32)
    return v / np.linalg.norm(v)


def _grad(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference gradient (d/dx, d/dy) per px of a (H, W) float32 image."""
    k = np.array([[-0.5, 0.0, 0.5]], np.float32)
    gx = cv2.filter2D(f, -1, k, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.filter2D(f, -1, k.T, borderType=cv2.BORDER_REPLICATE)
    return gx, gy


def _normal_dot(sx: np.ndarray, sy: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For the height-field normal n ∝ (−sx, −sy, 1): (n·d, n_z), both (H, W)."""
    inv = 1.0 / np.sqrt(1.0 + sx * sx + sy * sy)
    return (d[2] - d[0] * sx - d[1] * sy) * inv, inv


def _pow(x: np.ndarray, e: float) -> np.ndarray:
    """max(x, 0) ** e for float e > 0, via exp/log (float ``**`` is ~50x slower)."""
    return np.exp(e * np.log(np.maximum(x, 1e-12)))


def _roi(mask: np.ndarray, margin: int) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1): bounding box of ``mask`` grown by ``margin`` px, clipped to the image."""
    x, y, bw, bh = cv2.boundingRect(mask.astype(np.uint8))
    h, w = mask.shape
    return max(0, y - margin), min(h, y + bh + margin), max(0, x - margin), min(w, x + bw + margin)


def paint_objects(img: np.ndarray, labels: np.ndarray, table: np.ndarray, p) -> None:
    """Paint opaque objects into ``img`` (3, H, W), in place.

    Label k gets albedo ``table[k]`` (3,), shaded as a dome that rolls off over
    ``p.object_roundness_px`` px towards its silhouette (Lambert + a glossy highlight), with
    a fine surface texture fixed in the image.
    """
    obj_full = labels > 0
    if not obj_full.any():
        return
    h, w = labels.shape
    y0, y1, x0, x1 = _roi(obj_full, 2)
    lab, obj = labels[y0:y1, x0:x1], obj_full[y0:y1, x0:x1]
    edge = np.zeros_like(obj)
    dx = lab[:, 1:] != lab[:, :-1]
    dy = lab[1:, :] != lab[:-1, :]
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:, :] |= dy
    edge[:-1, :] |= dy
    dist = cv2.distanceTransform((obj & ~edge).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_3)
    r = float(p.object_roundness_px)
    dome = np.sqrt(np.minimum(dist * (1.0 / r), 1.0))
    dome = cv2.GaussianBlur(dome, (0, 0), 1.0)
    gx, gy = _grad(dome)
    gx *= r
    gy *= r
    light = _unit(p.light_dir)
    half = _unit(light + _VIEW)
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)        # n = (−gx, −gy, 1) · inv
    shade = np.maximum((light[2] - light[0] * gx - light[1] * gy) * inv, 0.0)
    shade *= 1.0 - p.ambient
    shade += p.ambient
    if p.object_texture > 0:     # fine surface texture, fixed in the image for a given seed
        rs = np.random.default_rng(p.texture.seed + 1)
        tex = cv2.resize(fast_gaussian(rs, (h // 2 + 1, w // 2 + 1)), (w, h))[y0:y1, x0:x1]
        shade *= 1.0 + p.object_texture * tex
    gloss = None
    if p.object_gloss > 0:
        gloss = p.object_gloss * _pow((half[2] - half[0] * gx - half[1] * gy) * inv, 20.0)
    win = img[:, y0:y1, x0:x1]
    for c in range(3):
        paint = np.take(table[:, c], lab) * shade
        if gloss is not None:
            paint += gloss * p.light_color[c]
        np.copyto(win[c], paint, where=obj)


def _col(c) -> np.ndarray:
    """RGB triple → (3, 1, 1) float32 for broadcasting over planes."""
    return np.asarray(c, np.float32)[:, None, None]


def paint_liquid(scene: np.ndarray, thickness: np.ndarray, mask: np.ndarray, p) -> None:
    """Paint transparent liquid into ``scene`` (3, H, W), in place.

    The liquid surface is a height field: the smoothed thickness (normalised by
    ``p.thickness_ref`` or its mean over the mask) plus a rounded edge of the mask. Its
    slope, relative to the steepest slope of a blurred step, displaces the background
    (cv2.remap, magnifying like a lens) by up to ``p.refraction_px`` px, tilts the normal for
    Fresnel reflection of ``p.env_color`` and a Blinn–Phong highlight, and bright rims line
    the edges. Transmission darkens/tints as exp(−absorption · thickness).
    """
    if not mask.any():
        return
    sig = float(p.surface_sigma_px)
    y0, y1, x0, x1 = _roi(mask, int(math.ceil(3 * sig)) + 4)
    m = mask[y0:y1, x0:x1]
    mf = m.astype(np.float32)
    ref = p.thickness_ref if p.thickness_ref else float(thickness[mask].mean())
    scale = np.float32(1.0 / ref if ref > 0 else 0.0)
    tn = np.clip(thickness[y0:y1, x0:x1].astype(np.float32) * scale, 0.0, 3.0)
    tn *= mf
    height = cv2.GaussianBlur(tn + p.edge_lift * mf, (0, 0), sig)
    sx, sy = _grad(height)
    gain = 2.5 * sig                     # 1 / (slope of a unit step blurred by sig), ≈ 1/0.4
    sx *= gain
    sy *= gain
    k = p.refraction_px / np.sqrt(1.0 + sx * sx + sy * sy)   # |D| saturates at refraction_px
    # source window: the ROI grown by the largest displacement and the blur support
    pad = int(math.ceil(p.refraction_px + 3 * p.liquid_blur_px)) + 2
    h, w = mask.shape
    sy0, sy1, sx0, sx1 = max(0, y0 - pad), min(h, y1 + pad), max(0, x0 - pad), min(w, x1 + pad)
    xs = np.arange(x0 - sx0, x1 - sx0, dtype=np.float32)[None, :]
    ys = np.arange(y0 - sy0, y1 - sy0, dtype=np.float32)[:, None]
    m1, m2 = cv2.convertMaps(xs + k * sx, ys + k * sy, cv2.CV_16SC2)
    refr = np.empty((3,) + m.shape, np.float32)
    for c in range(3):
        src = scene[c, sy0:sy1, sx0:sx1]
        if p.liquid_blur_px > 0:
            src = cv2.GaussianBlur(src, (0, 0), p.liquid_blur_px)
        cv2.remap(src, m1, m2, cv2.INTER_LINEAR, dst=refr[c], borderMode=cv2.BORDER_REFLECT)
    scratch = np.multiply(tn[None], -_col(p.absorption))    # (3, h, w) buffer, reused below
    refr *= np.exp(scratch, out=scratch)                     # Beer–Lambert transmission
    sx *= p.normal_tilt
    sy *= p.normal_tilt
    ndh, nz = _normal_dot(sx, sy, _unit(_unit(p.light_dir) + _VIEW))
    graze = 1.0 - nz                     # Schlick: F = F0 + (1 − F0)(1 − cos θ)^5
    g2 = graze * graze
    fres = p.fresnel + (1.0 - p.fresnel) * (g2 * g2 * graze)
    edge = cv2.GaussianBlur(mf, (0, 0), 1.0)
    ex, ey = _grad(edge)
    hi = np.minimum(np.sqrt(ex * ex + ey * ey) * 5.0, 1.0) * p.rim
    if p.specular > 0:
        hi += p.specular * _pow(ndh, p.shininess)
    refr *= 1.0 - fres
    for c in range(3):   # per plane: (h, w) temporaries instead of (3, h, w) ones
        refr[c] += fres * p.env_color[c] + hi * p.light_color[c]
    alpha = np.minimum(np.maximum(2.0 * edge, mf), 1.0)
    win = scene[:, y0:y1, x0:x1]
    np.subtract(refr, win, out=scratch)
    scratch *= alpha
    win += scratch
