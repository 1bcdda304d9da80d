"""Does a straight segment pass through object material? (camera occlusion; walls between
neighbour pairs, :mod:`liquidtwin.sim.walls`)

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

from . import fused
from .sdf import SDFGrid, check_poses, quat_to_matrix


def world_points(x, what: str = "points") -> torch.Tensor:
    """``x`` as a float (N, 3) tensor; ValueError if it is not one or holds NaN or inf."""
    x = torch.as_tensor(x)
    if x.dim() != 2 or x.shape[1] != 3:
        raise ValueError(f"{what} must be (N, 3) world positions in m, got shape {tuple(x.shape)}")
    if not x.is_floating_point():
        x = x.to(torch.get_default_dtype())
    if not bool(torch.isfinite(x).all()):
        raise ValueError(f"{what} contain NaN or inf")
    return x


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


def default_step(objects) -> float:
    """The march's default tolerance and smallest step: the thinnest wall / 4, m."""
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
    start = world_points(start, "segment starts")
    end = torch.as_tensor(end, dtype=start.dtype, device=start.device)
    if end.shape == (3,):
        end = end.expand_as(start)
    end = world_points(end, "segment ends")
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
    tol = default_step(objects) if tolerance is None else float(tolerance)
    step = default_step(objects) if min_step is None else float(min_step)
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
