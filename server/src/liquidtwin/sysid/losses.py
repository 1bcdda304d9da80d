"""Losses between a predicted state and the truth (thesis §8.3.1).

- :func:`l1_loss` needs particle correspondence: mean |x − x̂| and |v − v̂|·dt, both in
  units of the kernel radius h so positions and velocities weigh alike.
- :func:`projection_loss` needs none: both particle sets are drawn into a virtual camera as
  Gaussians passed through a sigmoid (:func:`liquidtwin.camera.splat`), only the particles
  the camera sees (objects occlude, :func:`seen`), and the images are compared by mean L1.
"""

from __future__ import annotations

import torch

from ..camera import splat, visible

#: Splat width and sigmoid of the projection image (px; thesis: "a small Gaussian").
SIGMA_PX = 1.5
GAIN, BIAS = 10.0, -5.0


def l1_loss(x: torch.Tensor, v: torch.Tensor, x_true: torch.Tensor, v_true: torch.Tensor, h: float,
            dt: float) -> torch.Tensor:
    """Mean L1 over particles of positions (N, 3) m and velocities (N, 3) m/s, both by id, in
    units of h (velocities times dt)."""
    return ((x - x_true).abs().mean() + (v - v_true).abs().mean() * dt) / h


def seen(camera, x: torch.Tensor, objects, poses: torch.Tensor) -> torch.Tensor:
    """(N,) bool: the particles x (N, 3) m the camera sees (in view, not behind an object)."""
    return visible(camera, x.detach(), objects, poses, margin_px=3 * SIGMA_PX)


def projection(camera, x: torch.Tensor, visible_mask: torch.Tensor) -> torch.Tensor:
    """(H, W) differentiable image of the particles x (N, 3) m where ``visible_mask`` (N,)."""
    uv, _ = camera.project(x)
    return splat(uv, visible_mask, camera.height, camera.width, sigma_px=SIGMA_PX, gain=GAIN, bias=BIAS)


def projection_loss(camera, x: torch.Tensor, visible_mask: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean |I(x) − target| over the image (no correspondence needed): ``target`` (H, W) the
    true state's :func:`projection`."""
    return (projection(camera, x, visible_mask) - target).abs().mean()
