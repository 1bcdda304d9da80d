"""Neighbour pairs that a wall separates (``FluidModel.wall_pairs = False``).

The neighbour search looks for particles within h and knows nothing of objects, so a
particle under a cup's 3 mm base counts the liquid inside the cup as neighbours: pressure
pushes through the wall, and cohesion holds a drop hanging on the outside of the cup (the
pouring task's last drops had 9-11 neighbours inside the cup: README, "Cohesion through
walls"). Real liquid on the two sides of a wall does not interact. With the cut, the pairs
whose straight segment passes through object material are dropped from the step's lists.

Which pairs, cheaply. Marching every pair's segment
(:func:`liquidtwin.sim.segments.segment_blocked`) costs several SDF samples per pair, and most
pairs of a small container lie along a wall. So first a rule per pair, from one SDF value and
normal per particle (its nearest object's): a wall lies between two particles only if one of
them lies beyond the tangent plane of the other's nearest surface point. Across a flat wall
of thickness t the other particle lies t plus its own clearance beyond that plane; where the
object is convex it lies behind the tangent plane altogether; at a concave corner the
particle on the outer, convex side sees the other beyond its plane. Pairs whose far particle
is less than ``t/4`` beyond the plane are kept without marching (the quarter wall the march
tolerates). It is a rule for walls, not a theorem for every shape: particles squeezed between
two objects, or a wall of another object than their nearest, can slip through it. Only the
few candidate pairs are marched. ``tests/server/test_walls.py`` checks the rule against
marching every pair, and the cut against an analytic slab.

Every neighbour list of the step is cut (the solver iterations' rebuilds and the one for
viscosity), with the objects at their end-of-step poses, where the iterations hold them. With
the C++ extension the rule, the march and the compaction run in one pass over the pairs.

The cut is a selection, like the neighbour search itself: it has no gradient.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from . import fused
from .collide import lower_bounds
from .sdf import cached_for, quat_to_matrix
from .segments import default_step, segment_blocked

def pair_rows(row_ptr: torch.Tensor) -> torch.Tensor:
    """(P,) int64 row (query) index of every CSR pair."""
    n = row_ptr.numel() - 1
    return torch.repeat_interleave(torch.arange(n, device=row_ptr.device), row_ptr[1:] - row_ptr[:-1])


def slack_for(objects) -> float:
    """How far beyond a tangent plane a particle must lie to be marched: −(thinnest wall)/4, m."""
    return -0.25 * min(float(o.thickness) for o in objects)


@torch.no_grad()
def facing_pairs(x: torch.Tensor, row_ptr: torch.Tensor, col: torch.Tensor, objects, poses: torch.Tensor,
                 slack: float, reach: float, *, native: bool = False) -> torch.Tensor:
    """Candidate pairs for a wall between them (module doc).

    Every particle whose lower-bound distance to some object is below ``reach`` takes its
    nearest object's SDF value s and outward unit normal n (the normalised gradient of the
    trilinear SDF, in the world frame). Pair (i, k) is a candidate when (x_i − x_k)·n_i >
    s_i − slack (x_k beyond i's tangent plane) or (x_i − x_k)·n_k < slack − s_k.

    Args:
      x: (N, 3) positions, m; row_ptr (N + 1,), col (P,): CSR neighbour pairs.
      objects, poses: the M :class:`SDFGrid` and their (M, 7) poses.
      slack: m (:func:`slack_for`); reach: m, particles further from every object are skipped.
      native: the same rule in one C++ pass (CPU, the extension built).
    Returns:
      (P,) bool.
    """
    if native:
        return fused.facing_pairs(x, row_ptr, col, poses, objects, slack, reach)
    rows = pair_rows(row_ptr)
    lbmin, nearest = lower_bounds(objects, x, poses, False).min(1)
    poses = poses.detach().to(x)
    rot = quat_to_matrix(poses[:, 3:])
    value = x.new_full((x.shape[0],), float("inf"))
    normal = x.new_zeros(x.shape[0], 3)
    close = lbmin < reach
    for j, o in enumerate(objects):
        near = torch.nonzero(close & (nearest == j)).flatten()
        if near.numel() == 0:
            continue
        with torch.enable_grad():
            p = ((x[near] - poses[j, :3]) @ rot[j]).requires_grad_(True)
            v = o.sample_local(p)
            (grad,) = torch.autograd.grad(v.sum(), p)
        value[near] = v.detach()
        normal[near] = F.normalize(grad, dim=1, eps=1e-12) @ rot[j].T
    sel = torch.nonzero(close[rows] | close[col]).flatten()
    r, c = rows[sel], col[sel]
    d = x[r] - x[c]
    hit = ((d * normal[r]).sum(1) > value[r] - slack) | ((d * normal[c]).sum(1) < slack - value[c])
    out = torch.zeros(rows.numel(), dtype=torch.bool, device=x.device)
    out[sel[hit]] = True
    return out


def pairs_through_walls(x: torch.Tensor, row_ptr: torch.Tensor, col: torch.Tensor, objects, poses: torch.Tensor,
                        *, native: bool = False, candidates: torch.Tensor | None = None) -> torch.Tensor:
    """(P,) bool: CSR pairs whose segment passes through object material (the march of
    :func:`~liquidtwin.sim.segments.segment_blocked` from the lower-indexed particle, so both
    directions of a pair agree). ``candidates`` (P,) bool: march only those (the rest False)."""
    rows = pair_rows(row_ptr)
    idx = torch.arange(col.numel(), device=x.device) if candidates is None else torch.nonzero(candidates).flatten()
    out = torch.zeros(col.numel(), dtype=torch.bool, device=x.device)
    if idx.numel() == 0:
        return out
    a, b = torch.minimum(rows[idx], col[idx]), torch.maximum(rows[idx], col[idx])
    out[idx] = segment_blocked(x.detach()[a], x.detach()[b], objects, poses, backend="auto" if native else "torch")
    return out


@torch.no_grad()
def cut_pairs(x: torch.Tensor, row_ptr: torch.Tensor, col: torch.Tensor, objects, poses: torch.Tensor, reach: float,
              *, native: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """CSR neighbour lists (row_ptr (N + 1,), col (P,)) of particles x (N, 3) m without the
    pairs a wall separates: :func:`facing_pairs` picks the candidates, the march of
    :func:`~liquidtwin.sim.segments.segment_blocked` (default tolerance and step) decides.
    ``native``: both in one C++ pass over the pairs."""
    slack, step = cached_for(tuple(objects), "wall cut", lambda: (slack_for(objects), default_step(objects)))
    if native:
        return fused.cut_wall_pairs(x, row_ptr, col, poses, objects, slack, reach, step, step)
    cut = pairs_through_walls(x, row_ptr, col, objects, poses,
                              candidates=facing_pairs(x, row_ptr, col, objects, poses, slack, reach))
    if not bool(cut.any()):
        return row_ptr, col
    keep = ~cut
    new_ptr = torch.zeros_like(row_ptr)
    new_ptr[1:] = torch.cumsum(torch.bincount(pair_rows(row_ptr)[keep], minlength=row_ptr.numel() - 1), 0)
    return new_ptr, col[keep]
