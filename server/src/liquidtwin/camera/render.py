"""Images of projected particles: model mask, coverage Φ, differentiable splats, IOU (SPEC §2).

Which pixels a disc covers (the one rule shared by :func:`model_mask` and :func:`coverage`):
a particle projected to (u, v) px is snapped to the nearest pixel centre
(U, V) = (⌊u + ½⌋, ⌊v + ½⌋) and covers every pixel (row i, column j) with
(j − U)² + (i − V)² ≤ radius². Pixel centres sit at integer (u, v) = (j, i) (OpenCV).
Discs are clipped at the image border; a particle outside the image still covers the
pixels of its disc that fall inside (if its ``visible`` flag is set).

Both are computed exactly by counting particles per (padded) pixel with ``bincount`` and
convolving the counts with the disc stencil: OpenCV on CPU, ``conv2d`` on other devices.
So ``model_mask(...) == (coverage(...) > 0)`` by construction.
"""

from __future__ import annotations

import math
import numbers

import cv2
import numpy as np
import torch
import torch.nn.functional as F


def _check_size(height, width) -> tuple[int, int]:
    for k, v in (("height", height), ("width", width)):
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise ValueError(f"image {k} must be a whole number of pixels, got {v!r}")
        if int(v) <= 0:
            raise ValueError(f"image {k} must be > 0 px, got {v}")
    return int(height), int(width)


def _visible_uv(uv, visible) -> torch.Tensor:
    """The (M, 2) rows of uv whose flag is set; checks shapes and finiteness of those rows."""
    uv = torch.as_tensor(uv)
    if uv.dim() != 2 or uv.shape[1] != 2:
        raise ValueError(f"uv must be (N, 2) pixel coordinates, got shape {tuple(uv.shape)}")
    if not uv.is_floating_point():
        uv = uv.to(torch.get_default_dtype())
    if visible is not None:
        visible = torch.as_tensor(visible, device=uv.device)
        if visible.shape != (len(uv),) or visible.dtype != torch.bool:
            raise ValueError(f"visible must be a ({len(uv)},) bool tensor, "
                             f"got {visible.dtype} {tuple(visible.shape)}")
        uv = uv[visible]
    if not bool(torch.isfinite(uv).all()):
        raise ValueError("uv of visible particles contains NaN or inf")
    return uv


def _check_radius(radius_px) -> tuple[float, int]:
    r = float(radius_px)
    if not (math.isfinite(r) and r >= 0):
        raise ValueError(f"radius_px must be finite and >= 0, got {radius_px}")
    return r, int(math.floor(r))


def disc_stencil(radius_px: float) -> np.ndarray:
    """(2R+1, 2R+1) uint8 stencil, R = ⌊radius⌋: 1 where dx² + dy² ≤ radius² (offsets in px)."""
    r, R = _check_radius(radius_px)
    d = np.arange(-R, R + 1)
    return ((d[:, None] ** 2 + d[None, :] ** 2) <= r * r).astype(np.uint8)


def _counts(uv: torch.Tensor, height: int, width: int, R: int) -> torch.Tensor:
    """Particles per snapped pixel, image padded by R on every side → (H+2R, W+2R) float32."""
    Hp, Wp = height + 2 * R, width + 2 * R
    c = torch.floor(uv.detach() + 0.5)
    ok = (c[:, 0] >= -R) & (c[:, 0] < width + R) & (c[:, 1] >= -R) & (c[:, 1] < height + R)
    c = c[ok].long() + R
    flat = torch.bincount(c[:, 1] * Wp + c[:, 0], minlength=Hp * Wp)
    return flat.to(torch.float32).reshape(Hp, Wp)


def _coverage_torch(counts: torch.Tensor, stencil: np.ndarray) -> torch.Tensor:
    k = torch.as_tensor(stencil, dtype=torch.float32, device=counts.device)[None, None]
    return F.conv2d(counts[None, None], k)[0, 0]  # 'valid' → (H, W)


def _disc_counts(uv, visible, height, width, radius_px):
    """Checked sizes, the disc's integer reach R, per-pixel particle counts on the image padded
    by R, and the disc stencil: what coverage and model_mask share."""
    H, W = _check_size(height, width)
    uv = _visible_uv(uv, visible)
    _, R = _check_radius(radius_px)
    return H, W, R, _counts(uv, H, W, R), disc_stencil(radius_px)


def coverage(uv, visible, height: int, width: int, radius_px: float = 5.0) -> torch.Tensor:
    """Coverage Φ: how many visible particle discs cover each pixel.

    Args:
      uv: (N, 2) projected particle positions, px (see :meth:`Camera.project`).
      visible: (N,) bool, particles to draw (None: all).
      height, width: image size, px.
      radius_px: disc radius, px (rule in the module doc).
    Returns:
      (H, W) int32 on uv's device.
    """
    H, W, R, counts, stencil = _disc_counts(uv, visible, height, width, radius_px)
    if counts.device.type != "cpu":
        return torch.round(_coverage_torch(counts, stencil)).to(torch.int32)
    out = cv2.filter2D(counts.numpy(), cv2.CV_32F, stencil.astype(np.float32),
                       borderType=cv2.BORDER_CONSTANT)
    return torch.from_numpy(np.rint(out[R:R + H, R:R + W]).astype(np.int32))


def model_mask(uv, visible, height: int, width: int, radius_px: float = 5.0) -> torch.Tensor:
    """Model mask (SPEC §2, thesis §8.4.3): union of the visible particles' discs.

    Args: as :func:`coverage`. Returns: (H, W) bool on uv's device, equal to ``coverage > 0``.
    """
    H, W, R, counts, stencil = _disc_counts(uv, visible, height, width, radius_px)
    if counts.device.type != "cpu":
        return _coverage_torch(counts, stencil) > 0.5
    hit = (counts.numpy() > 0).astype(np.uint8)
    out = cv2.dilate(hit, stencil, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return torch.from_numpy(out[R:R + H, R:R + W].astype(bool))


def _tent_gauss(d: torch.Tensor, sigma: float, trunc: float) -> torch.Tensor:
    """1-D Gaussian shifted and rescaled to fall to 0 at |d| = trunc·σ (peak 1): continuous."""
    c = math.exp(-0.5 * trunc * trunc)
    return ((torch.exp(-d * d / (2 * sigma * sigma)) - c) / (1 - c)).clamp(min=0)


def splat(uv, visible, height: int, width: int, sigma_px: float = 1.5, gain=10.0, bias=-5.0,
          truncate: float = 4.0) -> torch.Tensor:
    """Differentiable projection image (thesis §8.3.2): Gaussians summed, then a sigmoid.

    ``I(p) = sigmoid(gain · Σ_i g(p_u − u_i) · g(p_v − v_i) + bias)`` over visible particles
    i, p = (column, row) of each pixel centre, and
    ``g(d) ∝ max(exp(−d²/2σ²) − exp(−T²/2), 0)``
    scaled to g(0) = 1, T = ``truncate``: a separable Gaussian shifted to reach zero at
    |d| = T·σ, so the image is continuous in uv and each particle touches only a
    (2w+1)² window, w = ⌈Tσ + ½⌉ (memory and time O(N·w²), never O(N·H·W)).

    Args:
      uv: (N, 2) px, may require grad. visible: (N,) bool or None.
      height, width: image size, px. sigma_px: Gaussian std, px (> 0).
      gain, bias: sigmoid scale and offset (floats or scalar tensors, may require grad).
        Empty pixels read sigmoid(bias); the pixel under one lone particle centred on it
        reads sigmoid(gain + bias).
      truncate: support half-width in σ (> 0).
    Returns:
      (H, W) float in (0, 1), uv's dtype and device; differentiable w.r.t. uv, gain, bias.
    """
    H, W = _check_size(height, width)
    uv = _visible_uv(uv, visible)
    sigma, trunc = float(sigma_px), float(truncate)
    if not (math.isfinite(sigma) and sigma > 0 and math.isfinite(trunc) and trunc > 0):
        raise ValueError(f"sigma_px and truncate must be finite and > 0, "
                         f"got {sigma_px}, {truncate}")
    w = int(math.ceil(trunc * sigma + 0.5))
    base = torch.floor(uv.detach() + 0.5)
    near = (base[:, 0] >= -w) & (base[:, 0] < W + w) & (base[:, 1] >= -w) & (base[:, 1] < H + w)
    uv, base = uv[near], base[near].long()  # cast after the cull: huge values would overflow
    d = torch.arange(-w, w + 1, device=uv.device)
    px, py = base[:, 0:1] + d, base[:, 1:2] + d  # (M, 2w+1) pixel columns / rows of each window
    gx = _tent_gauss(px.to(uv.dtype) - uv[:, 0:1], sigma, trunc)
    gy = _tent_gauss(py.to(uv.dtype) - uv[:, 1:2], sigma, trunc)
    inside = ((py >= 0) & (py < H))[:, :, None] & ((px >= 0) & (px < W))[:, None, :]
    flat = torch.where(inside, py[:, :, None] * W + px[:, None, :], H * W)  # H·W: a discard slot
    acc = torch.zeros(H * W + 1, dtype=uv.dtype, device=uv.device)
    acc = acc.index_add(0, flat.reshape(-1), (gy[:, :, None] * gx[:, None, :]).reshape(-1))
    return torch.sigmoid(gain * acc[:-1].reshape(H, W) + bias)


def iou(a, b) -> float:
    """|a ∩ b| / |a ∪ b| of two bool masks of the same shape (e.g. (H, W)); 1.0 when both are
    empty (two empty masks agree perfectly)."""
    a, b = torch.as_tensor(a), torch.as_tensor(b)
    if a.dtype != torch.bool or b.dtype != torch.bool:
        raise ValueError(f"iou needs bool masks, got {a.dtype} and {b.dtype}")
    if a.shape != b.shape:
        raise ValueError(f"iou needs masks of the same shape, "
                         f"got {tuple(a.shape)} and {tuple(b.shape)}")
    union = int((a | b).sum())
    return 1.0 if union == 0 else int((a & b).sum()) / union


def sphere_radius_px(fx: float, depth: torch.Tensor, radius_m: float, *, min_px: float = 1.0,
                     max_px: float = 40.0) -> torch.Tensor:
    """Projected radius of a sphere of ``radius_m`` at ``depth`` (N,) m, px, rounded to half
    pixels (so particles fall into a few radius groups) and clamped to [min_px, max_px]."""
    r = (float(fx) * float(radius_m) / depth.clamp_min(1e-6)).clamp(min_px, max_px)
    return torch.round(r * 2.0) / 2.0


def sphere_coverage(uv, radius_px: torch.Tensor, visible, height: int, width: int) -> torch.Tensor:
    """Coverage Φ of visible particles drawn as discs of per-particle ``radius_px`` (N,) px
    (e.g. :func:`sphere_radius_px`): the sum of :func:`coverage` over the radius groups.
    Returns (H, W) int32 on uv's device; its ``> 0`` is the model mask of spheres."""
    H, W = _check_size(height, width)
    uv = torch.as_tensor(uv)
    keep = torch.ones(uv.shape[0], dtype=torch.bool, device=uv.device) if visible is None else visible.to(uv.device)
    out = torch.zeros((H, W), dtype=torch.int32, device=uv.device)
    r = radius_px.to(uv.device)
    for value in torch.unique(r[keep]).tolist():
        out += coverage(uv, keep & (r == value), H, W, radius_px=float(value)).to(out.device)
    return out
