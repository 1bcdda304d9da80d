"""Which particles a camera sees: in front, inside the image, and not hidden by an object.

A particle is **occluded** when the straight segment from it to the camera centre passes
through object material (SPEC §2); occluded particles are neither drawn nor corrected.

The segment test is batched sphere tracing over the objects' signed distance grids:

- Samples are taken at arc lengths s₀ = 0 < s₁ < … along the segment, with
  ``s_{k+1} = s_k + max(f(s_k), min_step)`` where f is a *lower bound* on the distance to
  the nearest object (inside a grid box it is the trilinear SDF; outside it,
  ``max(d_box, sdf_border − d_box)``, because the SDF grid sampled far from its box
  over-estimates the distance and could step over an object).
- The segment is **blocked** as soon as a sample lies deeper than ``tolerance`` inside
  material (f < −tolerance).
- Defaults: ``tolerance = min_step = t/4`` with t the thinnest wall of the objects
  (``SDFGrid.thickness``; 3 mm walls → 0.75 mm). A segment that crosses a wall has a
  stretch of at least t − 2·tolerance = t/2 = 2·min_step where f < −tolerance, and no
  step inside material is longer than min_step, so a full crossing of any wall of
  thickness ≥ t is never skipped, whatever the angle. Only a chord through a rim or
  corner shorter than about t/2 can slip through.
- A particle touching a wall (or up to ``tolerance`` inside it after the collision
  push-out) is not hidden by that wall unless its segment actually goes through it:
  leaving the surface the SDF rises, so f never drops below −tolerance.

Every sample advances by at least ``min_step``, so the loop ends after at most
distance/min_step rounds; rays leave the loop as they finish (hit or reach the camera).
On the CPU with the C++ extension built, the same march runs as one call with a ray per
thread (``backend="auto"``, equal to this torch loop: ``tests/server/test_camera.py``).
"""

from __future__ import annotations

import math

import torch

from ..sim import fused
from ..sim.sdf import SDFGrid, check_poses, quat_to_matrix
from .pinhole import Camera, _check_points


def _frames(objects, poses: torch.Tensor):
    """Per object: rotation R (3, 3), translation t (3,), grid box corners lo, hi (3,) in the
    object frame."""
    out = []
    for obj, pz in zip(objects, poses):
        lo = obj.origin.to(pz)
        hi = lo + (torch.tensor(obj.values.shape, dtype=pz.dtype, device=pz.device) - 1) * obj.cell
        out.append((quat_to_matrix(pz[3:]), pz[:3], lo, hi))
    return out


def _lower_bound_sdf(q: torch.Tensor, frames, objects) -> torch.Tensor:
    """min over objects of a lower bound on the distance to each, at world points (M, 3) → (M,)."""
    out = None
    for (R, t, lo, hi), obj in zip(frames, objects):
        p = (q - t) @ R  # object frame
        v = obj.sample_local(p)  # trilinear SDF, plus the distance to the grid box outside it
        outside = ((lo - p).clamp(min=0) + (p - hi).clamp(min=0)).norm(dim=-1)
        f = torch.where(outside > 0, torch.maximum(outside, v - 2 * outside), v)
        out = f if out is None else torch.minimum(out, f)
    return out


def _reaches_a_box(q: torch.Tensor, d: torch.Tensor, remaining: torch.Tensor, frames) -> torch.Tensor:
    """(M,) bool: does the segment q + τ·d, 0 ≤ τ ≤ remaining, meet any object's SDF grid box?
    Object material lies inside those boxes, so a segment that meets none cannot be blocked
    (slab test in each object's frame; q (M, 3), unit d (M, 3), remaining (M,))."""
    out = torch.zeros(len(q), dtype=torch.bool, device=q.device)
    for R, t, lo, hi in frames:
        p, u = (q - t) @ R, d @ R
        inv = 1.0 / torch.where(u.abs() < 1e-12, torch.full_like(u, 1e-12), u)
        a, b = (lo - p) * inv, (hi - p) * inv
        enter = torch.minimum(a, b).amax(dim=1).clamp(min=0.0)
        leave = torch.maximum(a, b).amin(dim=1).clamp(max=remaining)
        out |= enter <= leave
    return out


def _default_step(objects) -> float:
    return min(float(o.thickness) for o in objects) / 4.0


def segment_blocked(start: torch.Tensor, end: torch.Tensor, objects, poses: torch.Tensor,
                    tolerance: float | None = None, min_step: float | None = None, *,
                    backend: str = "auto") -> torch.Tensor:
    """Does the segment start[i] → end[i] pass through object material? (rule: module doc)

    Args:
      start: (N, 3) segment starts (particles), m, world frame.
      end: (N, 3) or (3,) segment ends (e.g. the camera centre), m.
      objects: sequence of M :class:`SDFGrid`; poses: (M, 7) object → world.
      tolerance: depth inside material that counts as a hit, m (default: thinnest wall / 4).
      min_step: smallest march step, m (default: thinnest wall / 4). Keep
        ``2·tolerance + min_step ≤ wall`` for the no-skip guarantee.
      backend: "auto" marches every ray in one C++/OpenMP call when the extension is built
        and the points are on the CPU (the same rule, one ray per thread instead of rounds
        of batched torch ops); "torch" always uses the torch loop, the reference.
    Returns:
      (N,) bool, True where blocked.
    """
    if backend not in ("auto", "torch"):
        raise ValueError(f"backend must be 'auto' or 'torch', got {backend!r}")
    start = _check_points(start, "segment starts")
    end = torch.as_tensor(end, dtype=start.dtype, device=start.device)
    if end.shape == (3,):
        end = end.expand_as(start)
    end = _check_points(end, "segment ends")
    if end.shape != start.shape:
        raise ValueError(f"segment ends must be (3,) or {tuple(start.shape)}, "
                         f"got {tuple(end.shape)}")
    objects = [objects] if isinstance(objects, SDFGrid) else list(objects)
    blocked = torch.zeros(len(start), dtype=torch.bool, device=start.device)
    if not objects or len(start) == 0:
        return blocked
    if not all(isinstance(o, SDFGrid) for o in objects):
        raise ValueError("objects must be SDFGrid instances")
    poses = torch.as_tensor(poses)
    check_poses(poses, len(objects))
    tol = _default_step(objects) if tolerance is None else float(tolerance)
    step = _default_step(objects) if min_step is None else float(min_step)
    if not (math.isfinite(tol) and tol >= 0 and math.isfinite(step) and step > 0):
        raise ValueError(f"need tolerance >= 0 and min_step > 0 (m), got {tolerance}, {min_step}")
    if backend == "auto" and fused.available(start.device):
        return fused.segment_blocked(start, end, poses, objects, tol, step)
    with torch.no_grad():
        poses = poses.detach().to(device=start.device, dtype=start.dtype)
        frames = _frames(objects, poses)
        delta = end.detach() - start.detach()
        length = delta.norm(dim=-1, keepdim=True)
        rays = torch.cat([start.detach(), delta / length.clamp(min=1e-30), length], 1)  # (N, 7)
        idx = torch.arange(len(start), device=start.device)
        s = torch.zeros(len(start), dtype=start.dtype, device=start.device)
        for _ in range(int(math.ceil(float(length.max()) / step)) + 2):
            if len(idx) == 0:
                break
            f = _lower_bound_sdf(rays[:, :3] + s[:, None] * rays[:, 3:6], frames, objects)
            hit = f < -tol
            blocked[idx[hit]] = True
            s = s + f.clamp(min=step)
            # rays whose rest meets no object's box are free: stop marching them
            free = ~_reaches_a_box(rays[:, :3] + s[:, None] * rays[:, 3:6], rays[:, 3:6],
                                   (rays[:, 6] - s).clamp(min=0.0), frames)
            keep = (~hit & ~free & (s < rays[:, 6])).nonzero().squeeze(1)
            idx, s, rays = idx[keep], s[keep], rays[keep]
    return blocked


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
