"""Which particles a camera sees: in front, inside the image, and not hidden by an object.

A particle is **occluded** when the straight segment from it to the camera centre passes
through object material (SPEC §2); occluded particles are neither drawn nor corrected.

The segment test (sphere tracing over the objects' signed distance grids, and why it never
skips a wall) lives in :mod:`liquidtwin.sim.segments`: the solver uses it too, to cut
neighbour pairs that a wall separates.
"""

from __future__ import annotations

import math

import torch

from ..sim.sdf import SDFGrid
from ..sim.segments import segment_blocked
from .pinhole import Camera, _check_points

__all__ = ["in_view", "segment_blocked", "visible"]


def in_view(camera: Camera, x: torch.Tensor, margin_px: float = 0.0,
            near: float = 0.0) -> torch.Tensor:
    """(N,) bool: depth > ``near`` m and the projected centre lies in the image grown by
    ``margin_px`` on each side (the image spans u ∈ [−0.5, W − 0.5), v ∈ [−0.5, H − 0.5)).
    x: (N, 3) world positions, m."""
    with torch.no_grad():
        uv, depth = camera.project(x.detach() if isinstance(x, torch.Tensor) else x)
    lo = -0.5 - margin_px
    u, v = uv[:, 0], uv[:, 1]
    return ((depth > near) & (u >= lo) & (u < camera.width - 0.5 + margin_px)
            & (v >= lo) & (v < camera.height - 0.5 + margin_px))


def visible(camera: Camera, x: torch.Tensor, objects=(), poses: torch.Tensor | None = None, *,
            margin_px: float = 0.0, near: float = 0.0, tolerance: float | None = None,
            min_step: float | None = None, backend: str = "auto") -> torch.Tensor:
    """Which particles the camera sees (SPEC §2).

    Args:
      camera: the :class:`Camera`.
      x: (N, 3) particle positions, m, world frame.
      objects: sequence of M :class:`SDFGrid` (opaque rigid objects); poses: (M, 7) their
        object → world poses (may be omitted when there are no objects).
      margin_px: also count particles projecting up to this many px outside the image
        (e.g. the disc radius, so discs straddling the border are drawn).
      near: minimum depth in front of the camera, m.
      tolerance, min_step, backend: sphere-tracing parameters, see :func:`segment_blocked`.
    Returns:
      (N,) bool on x's device: in front, inside the image and not occluded. Not
      differentiable (a selection).
    """
    x = _check_points(x, "particle positions")
    if not (math.isfinite(margin_px) and math.isfinite(near)):
        raise ValueError("margin_px and near must be finite")
    objects = [objects] if isinstance(objects, SDFGrid) else list(objects)
    if objects and poses is None:
        raise ValueError(f"poses (M, 7) are needed for the {len(objects)} objects")
    seen = in_view(camera, x, margin_px, near)
    if objects and bool(seen.any()):
        idx = seen.nonzero().squeeze(1)
        cam = camera.position.detach().to(device=x.device, dtype=x.dtype)
        hidden = segment_blocked(x.detach()[idx], cam, objects, poses, tolerance, min_step, backend=backend)
        seen[idx[hidden]] = False
    return seen
