"""Anti-clipped particle moves against rigid objects (SolveObjectCollisions, SPEC §1).

A move of the particles by ``delta`` while the objects go from ``pose_a`` to ``pose_b`` is
planned per object, then carried out piece by piece:

* **Plan** (:func:`plan_collisions`, no gradients). Particle i takes part for object j only
  if a lower bound on its distance to j at the start pose is below its reach |delta_i|
  plus how far j sweeps, plus how far *other* objects it touches sweep (they can push it),
  plus a margin of two of j's cells. The particle moves in as many pieces as make each
  piece (its own move plus those sweeps) at most a third of the wall of every object it
  takes part for. A fast particle splits its own move only: before stop 48 one fast
  particle near a wall set the piece count of every particle near that wall (3× the
  pieces in a full-size pour).
* **Move**. After every piece the particle is pushed out of its objects posed at the
  matching fraction of their motion, as :func:`~liquidtwin.sim.sdf.push_out` does:
  ``p += ReLU(c − SDF(p)) n̂`` with SDF = min over its objects and n̂ the normalised
  central-difference gradient. Objects a particle does not take part in cannot reach it
  (they read +inf), and the 6 stencil samples are only taken where the centre value is
  below c (elsewhere the push is exactly zero).
  :func:`move_torch` is differentiable (autograd w.r.t. positions, moves and poses);
  :func:`move_native` is one C++/OpenMP call for when no gradient is needed, and
  :func:`move_native_grad` the same call with a C++ backward pass for when one is.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from . import fused
from .sdf import _world_to_local, cached_for, interpolate_poses, quat_to_matrix, sweep_bound

PIECE_FRACTION = 1.0 / 3.0
"""Anti-clipping pieces (particle move + object sweeps) are at most this fraction of an
object's thinnest wall: a particle then penetrates at most a third of a wall, where the
sampled SDF (cells of at most a quarter wall) still points back to the side it came from."""

_STENCIL = torch.tensor([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], dtype=torch.float64)


@dataclass(frozen=True)
class Plan:
    """Which particles collide with which objects, and in how many pieces.

    Attributes:
      idx: (R,) int64 rows of the particles that take part, sorted by piece count, most first.
      active: (R, M) bool, object j can reach particle idx[r] during the move.
      pieces: (R,) int64 >= 1, pieces of particle idx[r] (non-increasing).
      counts: counts[s - 1] = number of rows with at least s pieces, s = 1 … pieces[0].
    """

    idx: torch.Tensor
    active: torch.Tensor
    pieces: torch.Tensor
    counts: tuple[int, ...]


def lower_bounds(objects, x: torch.Tensor, poses: torch.Tensor, native: bool) -> torch.Tensor:
    """(N, M) lower bounds on each object's SDF at points x (N, 3) m, objects at poses (M, 7)."""
    x, poses = x.detach(), poses.detach()
    if native:
        return fused.sdf_lower_bounds(x, poses, objects)
    return torch.stack([o.lower_bound_local(_world_to_local(x, poses[j])) for j, o in enumerate(objects)], 1)


def _push_from_others(active: torch.Tensor, sweep: torch.Tensor) -> torch.Tensor:
    """(N, M): largest sweep of another object each particle takes part in, m."""
    a = torch.where(active, sweep[None], torch.zeros((), dtype=sweep.dtype))
    if a.shape[1] == 1:
        return torch.zeros_like(a)
    top = a.topk(2, dim=1)
    first = torch.arange(a.shape[1], device=a.device)[None] == top.indices[:, :1]
    return torch.where(first, top.values[:, 1:2], top.values[:, :1])


def _margins(objects: tuple, collision_distance: float, dtype, device) -> tuple[torch.Tensor, tuple]:
    """Per object: the plan's margin (collision distance + two cells, m; (M,) tensor, read
    only) and longest piece (a third of its thinnest wall, m); made once per object set."""
    def make():
        margin = torch.tensor([collision_distance + 2.0 * o.cell for o in objects], dtype=dtype, device=device)
        return margin, tuple(PIECE_FRACTION * o.thickness for o in objects)
    return cached_for(objects, ("plan margins", collision_distance, dtype, device), make)


def plan_collisions(objects, x: torch.Tensor, delta: torch.Tensor, pose_a: torch.Tensor, pose_b: torch.Tensor,
                    collision_distance: float, max_pieces: int, native: bool = False,
                    pieces: int | None = None) -> Plan | None:
    """Plan an anti-clipped move (see the module docstring); None when nobody can collide.

    Args:
      x, delta: (N, 3) positions and move, m. pose_a, pose_b: (M, 7) object poses.
      collision_distance: particles are kept this far outside surfaces, m.
      max_pieces: cap on pieces per particle (a RuntimeWarning names any excess).
      native: plan with the C++ extension (same decisions, one call).
      pieces: force this piece count on every particle that takes part (tests).
    """
    fixed = pose_a is pose_b
    x, delta = x.detach(), delta.detach()
    pose_a, pose_b = pose_a.detach().to(x.dtype), pose_b.detach().to(x.dtype)
    m, dev = len(objects), x.device
    sweep = torch.zeros(m, dtype=x.dtype, device=dev) if fixed else sweep_bound(objects, pose_a, pose_b).to(x)
    margin, thin = _margins(tuple(objects), float(collision_distance), x.dtype, dev)
    if native:
        idx, active, count, counts, most = fused.collide_plan(x, delta, pose_a, objects, sweep, margin, thin,
                                                              max_pieces, pieces or 0)
        counts, most = tuple(counts.tolist()), int(most)
    else:
        idx, active, count, counts, most = _plan_torch(objects, x, delta, pose_a, sweep, margin, thin,
                                                       max_pieces, pieces)
    if most > max_pieces:
        worst = min(range(m), key=lambda j: thin[j] if bool(active[:, j].any()) else math.inf)
        warnings.warn(f"anti-clipping needs {most} pieces for this move but max_pieces is {max_pieces}: fast "
                      f"particles or objects may cross walls thinner than {thin[worst] / PIECE_FRACTION:.4f} m "
                      f"({objects[worst].name}); raise FluidModel.max_pieces or lower dt", RuntimeWarning)
    return Plan(idx, active, count, counts) if idx.numel() else None


def _plan_torch(objects, x, delta, pose_a, sweep, margin, thin, max_pieces, pieces):
    """:func:`plan_collisions` with torch ops → (idx, active, pieces, counts, uncapped max)."""
    m = len(objects)
    reach = delta.norm(dim=-1)
    start = lower_bounds(objects, x, pose_a, False)
    push = torch.zeros_like(start)
    active = start < reach[:, None] + push + sweep + margin
    if m > 1 and bool((sweep > 0).any()):
        for _ in range(m):  # moving objects may push particles on: grow until nothing changes
            push = _push_from_others(active, sweep)
            grown = start < reach[:, None] + push + sweep + margin
            if torch.equal(grown, active):
                break
            active = grown
    rows = torch.nonzero(active.any(1)).flatten()
    if rows.numel() == 0:
        return rows, active[rows], rows, (), 0
    active, travel = active[rows], (reach[:, None] + push)[rows]
    # Each particle's pieces: at most a third of every wall it can meet (in float64, as the C++).
    need = torch.ceil((travel.double() + sweep.double()[None]) / torch.tensor(thin, dtype=torch.float64,
                                                                              device=x.device)[None])
    count = torch.where(active, need.clamp(min=1).to(torch.int64), 0).max(1).values
    if pieces:
        count = torch.full_like(count, int(pieces))
    most = int(count.max())
    count = count.clamp(max=max_pieces)
    order = torch.sort(count, descending=True, stable=True).indices
    count = count[order]
    hist = torch.bincount(count, minlength=int(count[0]) + 1)
    at_least = hist.flip(0).cumsum(0).flip(0)[1:]
    return rows[order], active[order], count, tuple(int(c) for c in at_least), most


class _Motion:
    """An object's motion from pose a to pose b (7,) as :func:`interpolate_poses` does it."""

    def __init__(self, pa: torch.Tensor, pb: torch.Tensor, fixed: bool):
        self.pa, self.pb, self.fixed = pa, pb, fixed
        self.R_b = quat_to_matrix(pb[3:])
        if not fixed:
            q0, q1 = pa[3:] / pa[3:].norm(), pb[3:] / pb[3:].norm()
            self.q0, self.q1 = q0, q1 * torch.where((q0 * q1).sum() < 0, -1.0, 1.0).to(q0.dtype)

    def local(self, p: torch.Tensor, frac: torch.Tensor, last: torch.Tensor, uniform: float | None):
        """World points p (k, ..., 3) → object frame; row r posed at fraction frac[r] (k,)
        (the end pose where last[r]); ``uniform`` is the shared fraction when all rows agree."""
        if self.fixed or uniform == 1.0:
            t, R = self.pb[:3], self.R_b
        elif uniform is not None:
            pose = interpolate_poses(self.pa[None], self.pb[None], uniform)[0]
            t, R = pose[:3], quat_to_matrix(pose[3:])
        else:
            f = frac[:, None]
            q = self.q0 + (self.q1 - self.q0) * f
            q = q / q.norm(dim=-1, keepdim=True)
            t = self.pa[:3] + (self.pb[:3] - self.pa[:3]) * f
            q = torch.where(last[:, None], self.pb[3:], q)
            t = torch.where(last[:, None], self.pb[:3], t)
            R = quat_to_matrix(q)
            d = p - t.reshape((t.shape[0],) + (1,) * (p.dim() - 2) + (3,))
            return torch.einsum("k...b,kba->k...a", d, R)
        return ((p.reshape(-1, 3) - t) @ R).reshape(p.shape)  # as _world_to_local: one GEMM


def _push(p, active, frac, last, uniform, motions, objects, cd: float, dil: float):
    """One push-out of points p (n, 3) against their active objects (n, M) → (n, 3).

    frac (n,): fraction of the objects' motion for each row, last (n,) bool: rows at their
    last piece (end pose), uniform: the shared fraction when all rows agree, else None."""
    n, inf = p.shape[0], float("inf")
    sel, centre = [], []
    for j, o in enumerate(objects):
        rows = torch.nonzero(active[:, j]).flatten()
        sel.append(rows)
        if rows.numel() == 0:
            continue
        if rows.numel() == n:  # everyone: no gather, no scatter
            centre.append(o.sample_local(motions[j].local(p, frac, last, uniform)))
            continue
        v = o.sample_local(motions[j].local(p[rows], frac[rows], last[rows], uniform))
        centre.append(p.new_full((n,), inf).index_put((rows,), v))
    value = centre[0] if len(centre) == 1 else torch.stack(centre, 0).min(0).values
    pen = value.detach() < cd
    pen_rows = torch.nonzero(pen).flatten()
    if pen_rows.numel() == 0:
        return p
    rank = torch.cumsum(pen, 0) - 1
    offsets = _STENCIL.to(p) * dil
    sides = []
    for j, o in enumerate(objects):
        rows = sel[j]
        if rows.numel() == 0:
            continue
        rows = rows[pen[rows]]
        if rows.numel() == 0:
            continue
        pts = p[rows][:, None, :] + offsets[None]
        v = o.sample_local(motions[j].local(pts, frac[rows], last[rows], uniform))
        sides.append(p.new_full((pen_rows.numel(), 6), inf).index_put((rank[rows],), v))
    s = sides[0] if len(sides) == 1 else torch.stack(sides, 0).min(0).values
    normal = F.normalize(s[:, 1::2] - s[:, 0::2], dim=-1, eps=1e-12)
    depth = F.relu(cd - value[pen_rows])
    return p.index_add(0, pen_rows, depth[:, None] * normal)


def move_torch(objects, x: torch.Tensor, delta: torch.Tensor, pose_a: torch.Tensor, pose_b: torch.Tensor,
               plan: Plan, cd: float, dil: float) -> torch.Tensor:
    """Carry out ``plan`` with torch ops (differentiable). x, delta (N, 3) m → (N, 3) m.
    ``cd``: collision distance, m; ``dil``: normal finite-difference half step, m."""
    fixed = pose_a is pose_b
    motions = [_Motion(pose_a[j], pose_b[j], fixed) for j in range(len(objects))]
    S, first = plan.pieces, int(plan.pieces[0])
    cur = x[plan.idx]
    step = delta[plan.idx] / S.to(x.dtype)[:, None]
    done = []
    for s, n in enumerate(plan.counts, start=1):
        if n < cur.shape[0]:
            done.append(cur[n:])
            cur = cur[:n]
        cur = cur + step[:n]
        uniform = s / first if int(S[n - 1]) == first else None
        frac = (s / S[:n].double()).to(x.dtype)
        cur = _push(cur, plan.active[:n], frac, S[:n] == s, uniform, motions, objects, cd, dil)
    moved = torch.cat([cur] + done[::-1]) if done else cur
    return (x + delta).index_copy(0, plan.idx, moved)


def move_native_grad(objects, x: torch.Tensor, delta: torch.Tensor, pose_a: torch.Tensor, pose_b: torch.Tensor,
                     plan: Plan, cd: float, dil: float) -> torch.Tensor:
    """:func:`move_torch` as one C++ call with a C++ backward (CPU, float32/float64): the same
    values, and the gradients w.r.t. x, delta and the poses that autograd takes through
    :func:`move_torch`, without its thousands of small graph nodes."""
    return fused.collide_pieces_grad(x, delta, pose_a, pose_b, objects, plan.idx, plan.active, plan.pieces, cd,
                                     dil, pose_a is pose_b)


def move_native(objects, x: torch.Tensor, delta: torch.Tensor, pose_a: torch.Tensor, pose_b: torch.Tensor,
                plan: Plan, cd: float, dil: float) -> torch.Tensor:
    """:func:`move_torch` as one C++ call (forward only, CPU, float32/float64)."""
    return fused.collide_pieces(x.detach(), delta.detach(), pose_a.detach(), pose_b.detach(), objects,
                                plan.idx, plan.active, plan.pieces, cd, dil, pose_a is pose_b)
