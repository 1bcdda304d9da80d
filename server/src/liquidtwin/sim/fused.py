"""Fused PBF pair passes: the C++/OpenMP kernels of ``liquidtwin._native`` as autograd
functions, with the same results as the ConvSP compositions of :mod:`liquidtwin.sim.pbf`.

Each pass is one gather over the (symmetric) neighbour lists instead of several ConvSP
calls; backward passes are hand-derived, checked by ``gradcheck`` in float64 and against
the pure-torch reference in the tests. Used on CPU tensors when the extension is built.
"""

from __future__ import annotations

import functools

import torch

from .sdf import cached_for

try:  # built by server/setup.py at install time
    from liquidtwin import _native
except ImportError:  # pragma: no cover - exercised only on installs without a compiler
    _native = None


def available(device: torch.device | str = "cpu") -> bool:
    """True when the fused kernels can run on ``device``."""
    return _native is not None and torch.device(device).type == "cpu"


def sorted_neighbors(x: torch.Tensor, radius: float):
    """Cell-sort ``x`` (N, 3) and list neighbours closer than ``radius`` (self excluded).

    Returns (order (N,) int64, row_ptr (N+1,) int64, col (P,) int64); row i and the indices
    in ``col`` refer to the *sorted* points ``x[order]``.
    """
    return _native.sorted_neighbors(x.detach().cpu(), float(radius))


class _DensityNormals(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, row_ptr, col, h):
        rho, cnt, nrm = _native.density_normals(x.contiguous(), row_ptr, col, h)
        ctx.save_for_backward(x, row_ptr, col)
        ctx.h = h
        ctx.mark_non_differentiable(cnt)
        return rho, cnt, nrm

    @staticmethod
    def backward(ctx, g_rho, g_cnt, g_nrm):
        x, row_ptr, col = ctx.saved_tensors
        g_rho = torch.zeros(x.shape[0], dtype=x.dtype) if g_rho is None else g_rho
        g_nrm = torch.zeros_like(x) if g_nrm is None else g_nrm
        gx = _native.density_normals_backward(x.contiguous(), row_ptr, col, ctx.h, g_rho, g_nrm)
        return gx, None, None, None


class _PressureTension(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, omega, nrm, row_ptr, col, h):
        P, T = _native.pressure_tension(x.contiguous(), row_ptr, col, h, omega, nrm)
        ctx.save_for_backward(x, omega, row_ptr, col)
        ctx.h = h
        return P, T

    @staticmethod
    def backward(ctx, g_P, g_T):
        x, omega, row_ptr, col = ctx.saved_tensors
        g_P = torch.zeros_like(x) if g_P is None else g_P
        g_T = torch.zeros_like(x) if g_T is None else g_T
        gx, gw, gn = _native.pressure_tension_backward(x.contiguous(), row_ptr, col, ctx.h, omega, g_P, g_T)
        return gx, gw, gn, None, None, None


class _Viscosity(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, v, row_ptr, col, h):
        U = _native.viscosity(x.contiguous(), row_ptr, col, h, v)
        ctx.save_for_backward(x, v, row_ptr, col)
        ctx.h = h
        return U

    @staticmethod
    def backward(ctx, g_U):
        x, v, row_ptr, col = ctx.saved_tensors
        gx, gv = _native.viscosity_backward(x.contiguous(), row_ptr, col, ctx.h, v, g_U.contiguous())
        return gx, gv, None, None, None


def _tracked(*tensors) -> bool:
    """Whether autograd records a call on ``tensors`` (else the kernels are called directly:
    the same results without an autograd node per call)."""
    return torch.is_grad_enabled() and any(t.requires_grad for t in tensors)


def density_normals(x, row_ptr, col, h):
    """(ρ (N,), neighbour count (N,), surface normal n (N, 3)) — see pbf.density_normals."""
    if not _tracked(x):
        return tuple(_native.density_normals(x.contiguous(), row_ptr, col, float(h)))
    return _DensityNormals.apply(x, row_ptr, col, float(h))


def pressure_tension(x, omega, nrm, row_ptr, col, h):
    """(pressure sum (N, 3), tension sum (N, 3)) — see pbf.pressure_tension."""
    if not _tracked(x, omega, nrm):
        return tuple(_native.pressure_tension(x.contiguous(), row_ptr, col, float(h), omega, nrm))
    return _PressureTension.apply(x, omega, nrm, row_ptr, col, float(h))


def viscosity(x, v, row_ptr, col, h):
    """Σ_j W_ρ(d_ij)(v_j − v_i) (N, 3) — see pbf.viscosity_sum."""
    if not _tracked(x, v):
        return _native.viscosity(x.contiguous(), row_ptr, col, float(h), v)
    return _Viscosity.apply(x, v, row_ptr, col, float(h))


def _grids(objects, dtype):
    """SDF values (nx, ny, nz) in ``dtype``, origins (M, 3) and cells (M,) of ``objects``; the
    same tensors for the same objects (every collision call of every step asks again; the
    kernels only read them)."""
    objects = tuple(objects)

    def make():
        grids = [o._converted("values", "cpu", dtype) for o in objects]
        origins = torch.stack([o._converted("origin", "cpu", torch.float64).detach() for o in objects])
        cells = torch.tensor([float(o.cell) for o in objects], dtype=torch.float64)
        return grids, origins, cells
    return cached_for(objects, ("native grids", dtype), make)


def segment_blocked(start, end, poses, objects, tolerance: float, min_step: float):
    """:func:`liquidtwin.camera.occlusion.segment_blocked` in one C++ call, one ray per thread:
    start, end (N, 3) m; objects at poses (M, 7) → (N,) bool (no gradient)."""
    grids, origins, cells = _grids(objects, start.dtype)
    return _native.segment_blocked(start.detach().contiguous(), end.detach().to(start.dtype).contiguous(),
                                   poses.detach().to(start.dtype), grids, origins, cells, float(tolerance),
                                   float(min_step))


def facing_pairs(x, row_ptr, col, poses, objects, slack: float, reach: float, tolerance: float = 0.0,
                 min_step: float = 0.0):
    """:func:`liquidtwin.sim.walls.facing_pairs` in one C++ pass: (P,) bool (no gradient). With
    ``min_step`` > 0 the candidates are also marched (:func:`segment_blocked`'s rule): True
    marks the pairs a wall separates."""
    grids, origins, cells = _grids(objects, x.dtype)
    return _native.facing_pairs(x.detach().contiguous(), row_ptr, col, poses.detach().to(x.dtype), grids, origins,
                                cells, float(slack), float(reach), float(tolerance), float(min_step))


def cut_wall_pairs(x, row_ptr, col, poses, objects, slack: float, reach: float, tolerance: float, min_step: float):
    """:func:`liquidtwin.sim.walls.cut_pairs` in one C++ call: (row_ptr, col) without the pairs
    :func:`facing_pairs` (with the march) marks; the inputs themselves when none is."""
    grids, origins, cells = _grids(objects, x.dtype)
    return tuple(_native.cut_wall_pairs(x.detach().contiguous(), row_ptr, col, poses.detach().to(x.dtype), grids,
                                        origins, cells, float(slack), float(reach), float(tolerance), float(min_step)))


def sdf_lower_bounds(x, poses, objects):
    """(N, M) lower bounds on every object's SDF at points x (N, 3) m, objects at poses (M, 7)
    — :meth:`SDFGrid.lower_bound_local` in one C++ pass (no gradient)."""
    grids, origins, cells = _grids(objects, x.dtype)
    return _native.sdf_lower_bounds(x.detach().contiguous(), poses.detach().to(x.dtype), grids, origins, cells)


def collide_pieces(x, delta, pose_a, pose_b, objects, idx, active, pieces, collision_distance, dilation, fixed):
    """Anti-clipped move of particles ``idx`` (R,) in ``pieces`` (R,) pieces each, pushed out of
    their ``active`` (R, M) objects after every piece (see :mod:`liquidtwin.sim.collide`).
    x, delta (N, 3) m; poses (M, 7); ``fixed``: objects stay at pose_b. Forward only → (N, 3)."""
    grids, origins, cells = _grids(objects, x.dtype)
    return _native.collide_pieces(x.detach().contiguous(), delta.detach(), pose_a.detach(), pose_b.detach(), grids,
                                  origins, cells, idx, active, pieces, float(collision_distance), float(dilation),
                                  bool(fixed))


class _CollidePieces(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, delta, pose_a, pose_b, objects, idx, active, pieces, collision_distance, dilation, fixed):
        ctx.save_for_backward(x.detach(), delta.detach(), pose_a.detach(), pose_b.detach())
        ctx.objects, ctx.plan = objects, (idx, active, pieces, float(collision_distance), float(dilation), bool(fixed))
        return collide_pieces(x, delta, pose_a, pose_b, objects, *ctx.plan)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, g):
        x, delta, pose_a, pose_b = ctx.saved_tensors
        grids, origins, cells = _grids(ctx.objects, x.dtype)
        gx, gd, ga, gb = _native.collide_pieces_backward(x.contiguous(), delta, pose_a, pose_b, grids, origins, cells,
                                                         *ctx.plan, g.contiguous())
        fixed = ctx.plan[-1]
        return (gx, gd.to(delta.dtype), None if fixed else ga.to(pose_a.dtype), gb.to(pose_b.dtype),
                None, None, None, None, None, None, None)


def collide_pieces_grad(x, delta, pose_a, pose_b, objects, idx, active, pieces, collision_distance, dilation,
                        fixed):
    """:func:`collide_pieces` as an autograd function: gradients w.r.t. x, delta and both
    poses from one C++ backward pass (``fixed``: pose_a is pose_b, whose gradient gets it all)."""
    return _CollidePieces.apply(x, delta, pose_a, pose_b, objects, idx, active, pieces, collision_distance,
                                dilation, fixed)


def collide_plan(x, delta, pose_a, objects, sweep, margin, thin, max_pieces, forced=0):
    """The collision plan of :func:`liquidtwin.sim.collide.plan_collisions` in one C++ pass:
    x, delta (N, 3) m; pose_a (M, 7); sweep, margin (M,) m; thin (M,) longest piece, m.
    Returns idx (R,), active (R, M) bool, pieces (R,), counts (S,), uncapped max (0-d)."""
    grids, origins, cells = _grids(objects, x.dtype)
    return _native.collide_plan(x.detach().contiguous(), delta.detach(), pose_a.detach(), grids, origins, cells,
                                sweep, margin, _as_tensor(tuple(thin)), int(max_pieces), int(forced))


@functools.lru_cache(maxsize=64)
def _as_tensor(values: tuple) -> torch.Tensor:
    """A float64 tensor of ``values`` (the same one for the same values; read only)."""
    return torch.tensor(values, dtype=torch.float64)
