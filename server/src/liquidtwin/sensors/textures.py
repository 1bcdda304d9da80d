"""Procedural backgrounds (table tops, walls, cloths) for synthetic RGB frames.

Every texture is a deterministic function of its :class:`TextureParams` (which hold their own
seed), so one recording can reuse the same background for every frame.
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass

import cv2
import numpy as np

from ._common import SensorInputError, check_generator, fast_gaussian, smooth_noise

KINDS = ("checker", "stripes", "noise", "wood", "tiles", "clutter")


@dataclass(frozen=True)
class TextureParams:
    """One procedural texture.

    kind:      one of ``KINDS``
    colors:    two RGB colours ((r, g, b), (r, g, b)), each channel in [0, 1]
    scale_px:  feature size (checker cell, stripe period, tile, noise blob), px
    angle_rad: in-plane rotation of the pattern, rad
    warp:      domain warp amplitude relative to scale_px (0 = straight lines)
    grain:     amplitude of fine pixel-scale noise, [0, 1]
    seed:      seed of the texture's own random details
    """

    kind: str = "noise"
    colors: tuple = ((0.55, 0.5, 0.45), (0.25, 0.22, 0.2))
    scale_px: float = 16.0
    angle_rad: float = 0.0
    warp: float = 0.1
    grain: float = 0.03
    seed: int = 0

    def __post_init__(self):
        if self.kind not in KINDS:
            raise SensorInputError(f"texture kind must be one of {KINDS}, got {self.kind!r}")
        c = np.asarray(self.colors, dtype=np.float64)
        if c.shape != (2, 3) or not np.isfinite(c).all() or (c < 0).any() or (c > 1).any():
            raise SensorInputError(
                f"texture colors must be two RGB triples in [0, 1], got {self.colors!r}")
        if not (math.isfinite(self.scale_px) and self.scale_px >= 1.0):
            raise SensorInputError(f"texture scale_px must be ≥ 1 px, got {self.scale_px!r}")
        object.__setattr__(self, "colors", tuple(tuple(float(v) for v in row) for row in c))

    @staticmethod
    def sample(rng: np.random.Generator) -> "TextureParams":
        """A random texture: kind uniform over KINDS, random palette, scale 6–80 px, any angle."""
        check_generator(rng)
        kind = KINDS[int(rng.integers(len(KINDS)))]
        h, s, v = rng.uniform(0, 1), rng.uniform(0.0, 0.7), rng.uniform(0.25, 0.9)
        if kind == "wood":
            h, s = rng.uniform(0.04, 0.11), rng.uniform(0.35, 0.75)
        dv = rng.uniform(0.15, 0.55) * (1 if v < 0.55 else -1)
        dh = rng.uniform(-0.08, 0.08) if rng.random() < 0.7 else rng.uniform(0, 1)
        c0 = colorsys.hsv_to_rgb(h, s, v)
        c1 = colorsys.hsv_to_rgb((h + dh) % 1.0, float(np.clip(s + rng.uniform(-0.2, 0.2), 0, 1)),
                                 float(np.clip(v + dv, 0.02, 1.0)))
        scale = math.exp(rng.uniform(math.log(6), math.log(80)))
        return TextureParams(kind=kind, colors=(c0, c1), scale_px=scale,
                             angle_rad=rng.uniform(0, math.pi), warp=rng.uniform(0.0, 0.3),
                             grain=rng.uniform(0.0, 0.06), seed=int(rng.integers(2**31)))


def random_texture(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(height, width, 3) float32 RGB in [0, 1] of a random texture (``TextureParams.sample``)."""
    return render_texture(TextureParams.sample(rng), height, width)


def render_texture(params: TextureParams, height: int, width: int) -> np.ndarray:
    """(height, width, 3) float32 RGB in [0, 1]; deterministic in ``params``."""
    return cv2.merge(list(texture_planes(params, height, width)))


def texture_planes(params: TextureParams, height: int, width: int) -> np.ndarray:
    """The texture as (3, height, width) float32 colour planes (the layout the renderer uses)."""
    if int(height) < 1 or int(width) < 1:
        raise SensorInputError(f"texture size must be positive, got {height}×{width}")
    h, w = int(height), int(width)
    r = np.random.default_rng(params.seed)
    s = float(params.scale_px)
    xs = np.arange(w, dtype=np.float32)[None, :]
    ys = np.arange(h, dtype=np.float32)[:, None]
    ca, sa = math.cos(params.angle_rad), math.sin(params.angle_rad)
    u = ca * xs + sa * ys
    v = ca * ys - sa * xs
    if params.warp > 0:
        u = u + (params.warp * s) * smooth_noise(r, h, w, 3 * s)
        v = v + (params.warp * s) * smooth_noise(r, h, w, 3 * s)
    t = np.broadcast_to(_PATTERNS[params.kind](u, v, s, r, h, w), (h, w))
    c0 = np.asarray(params.colors[0], np.float32)[:, None, None]
    dc = np.asarray(params.colors[1], np.float32)[:, None, None] - c0
    img = c0 + t[None] * dc
    if params.grain > 0:   # grey pixel-scale grain
        img += params.grain * fast_gaussian(r, (h, w))[None]
    return np.clip(img, 0.0, 1.0, out=img)


def _soft(x: np.ndarray, width: float) -> np.ndarray:
    """Smooth step of a signed distance-like value over ``width`` (anti-aliased edges)."""
    return np.clip(0.5 + x / width, 0.0, 1.0)


def _wrap(x: np.ndarray, period: float) -> np.ndarray:
    """x wrapped into [−period/2, period/2) (signed distance to the nearest grid line)."""
    return x - period * np.floor(x * (1.0 / period) + 0.5)


def _checker(u, v, s, r, h, w):
    # product of two square waves, each ramping over ~1 px at its edges (anti-aliased)
    k = s / math.pi
    a = np.clip(np.sin(u * (math.pi / s)) * k, -1.0, 1.0)
    b = np.clip(np.sin(v * (math.pi / s)) * k, -1.0, 1.0)
    return 0.5 + 0.5 * a * b


def _stripes(u, v, s, r, h, w):
    hard = r.uniform(0.3, 6.0)
    return np.clip(0.5 + hard * np.sin(u * (2 * math.pi / s)), 0.0, 1.0)


def _noise(u, v, s, r, h, w):
    f = smooth_noise(r, h, w, s)
    f += 0.5 * smooth_noise(r, h, w, s / 2)
    f += 0.25 * smooth_noise(r, h, w, s / 4)
    return np.clip(0.5 + 0.3 * f, 0.0, 1.0)


def _wood(u, v, s, r, h, w):
    grain = v / s + 1.5 * smooth_noise(r, h, w, 6 * s) + 0.15 * smooth_noise(r, h, w, s)
    rings = 0.5 + 0.5 * np.sin(2 * math.pi * grain)
    rings = rings * rings * rings
    plank = 12 * s
    seams = np.abs(_wrap(v, plank)) < 1.0
    rings[seams] = 1.0
    return rings.astype(np.float32)


def _tiles(u, v, s, r, h, w):
    size = 2.5 * s
    du = np.abs(_wrap(u, size))
    dv = np.abs(_wrap(v, size))
    grout = np.minimum(du, dv)
    return 1.0 - _soft(grout - 0.06 * size, 1.0)


def _clutter(u, v, s, r, h, w):
    img = np.clip(0.5 + 0.2 * smooth_noise(r, h, w, 4 * s), 0, 1)
    for _ in range(int(r.integers(8, 30))):
        val = float(r.uniform(0, 1))
        cx, cy = int(r.integers(w)), int(r.integers(h))
        size = int(r.uniform(0.5, 3.0) * s) + 1
        if r.random() < 0.5:
            cv2.circle(img, (cx, cy), size, val, -1, cv2.LINE_AA)
        else:
            cv2.rectangle(img, (cx - size, cy - size // 2), (cx + size, cy + size // 2), val, -1,
                          cv2.LINE_AA)
    return img


_PATTERNS = {"checker": _checker, "stripes": _stripes, "noise": _noise, "wood": _wood,
             "tiles": _tiles, "clutter": _clutter}
