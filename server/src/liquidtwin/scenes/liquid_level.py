"""How much liquid a container holds, read off the particles and the container's geometry.

The liquid is taken to fill the container's cavity from its floor up to a free surface half
a particle layer above the topmost particles, wherever particles are: the cavity is cut
into vertical columns (a quarter spacing wide, each with its exact floor and top from the
cavity mesh), a column is wet when a particle lies within 0.65 spacing of it horizontally,
and its liquid reaches the mean height of the top particles near it plus half a layer.
The volume is the sum over wet columns. For liquid that covers the container's floor this
is what the cavity holds below a flat surface at that height (what a real container holds
when its liquid stands there); for a puddle that covers part of a plate, it is the
puddle's area times its depth.

It is not the particle count times a nominal particle volume: settled PBF liquid packs
much denser than the rest lattice (no boundary particles: particles against walls and floor
miss neighbours and the liquid compresses until their density sums reach the rest density).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch

from ..geometry import ObjectModel, _rays
from ..sim import FluidModel, FluidState, find_neighbors, iterations_for_impact, quat_to_matrix

WET_REACH = 0.65     # spacings: how far from a particle a column still holds liquid
TOP_REACH = 1.0      # spacings: top particles averaged for a column's surface
_SQUASH = torch.tensor([1.0, 1e-4, 1.0], dtype=torch.float64)   # heights squashed: columns


def fall_height(poses, objects, containers) -> float:
    """The longest free fall (m) liquid can take between containers: from the highest rim
    (pose height + rim height, upright) down to the lowest floor (pose height). ``poses``
    (M, 7); ``objects``: the M :class:`ObjectModel` s; ``containers``: indices of the
    containers among them. 0 with none."""
    poses = np.asarray(poses, float)
    ks = list(containers)
    if not ks:
        return 0.0
    top = max(float(poses[k, 1]) + float(objects[k].rim_height) for k in ks)
    return max(top - min(float(poses[k, 1]) for k in ks), 0.0)


def impact_iterations(poses, objects, containers, dt: float, spacing: float, least: int = 1) -> int:
    """Solver iterations that take the fastest impact between ``containers`` (a free fall over
    :func:`fall_height`, landing at sqrt(2 g fall)) without throwing liquid back out
    (``sim.iterations_for_impact``), and at least ``least``."""
    speed = math.sqrt(2.0 * 9.81 * fall_height(poses, objects, containers))
    return iterations_for_impact(speed, dt, spacing, least=least)


def rotation(pose: torch.Tensor) -> np.ndarray:
    """(3, 3) float64 rotation of a (7,) pose (object → world)."""
    return quat_to_matrix(pose[3:].detach().to(torch.float64)).numpy()


def held(model: FluidModel, state: FluidState, index: int,
         obj: ObjectModel) -> tuple[np.ndarray, np.ndarray]:
    """(mask (N,) bool, object-frame positions (N, 3) m) of the particles container ``index``
    (``model.objects[index]``, pose ``state.poses[index]``) holds.

    A particle counts when it is inside the cavity (or up to a spacing above the rim, in the
    opening's column). Particles resting on the inner wall may sit a hair inside the exact
    wall (the simulator works on a sampled SDF), so each is first moved to half a wall from
    the nearest surface along the SDF gradient: towards the cavity from the inner wall, away
    from it from the outer wall.
    """
    keep, probe, local = held_probes(model, state, index, obj)
    return keep & obj.in_cavity(probe), local


def held_probes(model: FluidModel, state: FluidState, index: int,
                obj: ObjectModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first half of :func:`held`: (keep (N,) bool, probe points (N, 3), object-frame
    positions (N, 3)), m; a particle is held when ``keep`` and its probe is in the cavity."""
    pose = state.poses[index].detach().to(torch.float64)
    R = rotation(pose)
    local = (state.x.detach().to(torch.float64).cpu().numpy() - pose[:3].numpy()) @ R
    grid = model.objects[index]
    p = torch.as_tensor(local, dtype=grid.values.dtype, device=grid.values.device)
    e = 0.5 * grid.cell
    sdf = lambda x: grid.sample_local(x).double().cpu().numpy()  # noqa: E731
    d = sdf(p)
    grad = np.stack([sdf(p + e * u) - sdf(p - e * u)
                     for u in torch.eye(3, dtype=p.dtype, device=p.device)], 1)
    grad /= np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
    probe = local + np.clip(0.5 * obj.wall - d, 0.0, obj.wall)[:, None] * grad
    rim = obj.rim_height
    keep = probe[:, 1] <= rim + model.spacing
    probe[:, 1] = np.minimum(probe[:, 1], rim - 1e-9)
    return keep, probe, local


def nearest_spacing(x: np.ndarray, spacing: float) -> float:
    """Median nearest-neighbour distance (m) of points (N, 3) with a neighbour within two
    rest ``spacing`` s (the rest spacing when none has one)."""
    t = torch.as_tensor(x, dtype=torch.float64)
    nb = find_neighbors(t, None, 2.0 * spacing)
    if nb.num_pairs == 0:
        return spacing
    rows = nb.rows()
    d = (t[rows] - t[nb.col]).norm(dim=1)
    best = torch.full((len(t),), math.inf, dtype=torch.float64).scatter_reduce(0, rows, d, "amin")
    return float(best[torch.isfinite(best)].median())


def top_particles(local: np.ndarray, spacing: float) -> np.ndarray:
    """(N,) bool: particles (N, 3) with no other particle above them within 0.6 spacing
    horizontally (the liquid's top layer)."""
    nb = find_neighbors(torch.as_tensor(local, dtype=torch.float64) * _SQUASH, None, 0.6 * spacing)
    rows, col = nb.rows(), nb.col
    y = torch.as_tensor(local[:, 1])
    covered = torch.zeros(len(local), dtype=torch.bool)
    covered[rows[y[col] > y[rows]]] = True
    return ~covered.numpy()


def surface_height(local: np.ndarray, spacing: float) -> float:
    """Mean height (m) of the free surface over settled particles at positions (N, 3), m:
    half a layer (√0.75·s/2, s the median nearest-neighbour distance) above the mean height
    of the top particles. For the rest lattice that is exactly the boundary of the volume
    its particles stand for."""
    layer = math.sqrt(0.75) * nearest_spacing(local, spacing)
    return float(local[top_particles(local, spacing), 1].mean() + 0.5 * layer)


@lru_cache(maxsize=32)
def _columns(obj: ObjectModel, cell: float):
    """Vertical columns through the cavity: (xz (K, 2) centres, interval column (I,),
    bottoms (I,), tops (I,) m, cell m, scale) — scale makes the columns' total equal the
    exact capacity (it corrects the staircase at the walls, a fraction of a percent)."""
    lo, hi = obj.cavity.bounds
    xs = np.arange(lo[0] + 0.5 * cell, hi[0], cell)
    zs = np.arange(lo[2] + 0.5 * cell, hi[2], cell)
    xz = np.stack(np.meshgrid(xs, zs, indexing="ij"), -1).reshape(-1, 2)
    col, y = _rays.column_hits(obj.cavity.vertices, obj.cavity.faces, xz)
    first = np.r_[True, col[1:] != col[:-1]]
    rank = np.arange(len(col)) - np.maximum.accumulate(np.where(first, np.arange(len(col)), 0))
    start = rank % 2 == 0                                          # entering the cavity
    pair = start[:-1] & (col[1:] == col[:-1])
    bottom, top, owner = y[:-1][pair], y[1:][pair], col[:-1][pair]
    used, owner = np.unique(owner, return_inverse=True)
    total = float(((top - bottom) * cell * cell).sum())
    scale = obj.capacity_ml / 1e6 / total if total > 0 else 1.0
    return xz[used], owner, bottom, top, scale


def settled_volume(model: FluidModel, state: FluidState, index: int, obj: ObjectModel):
    """Liquid container ``index`` holds: (ml, mean surface height m in the object frame over
    the wet area, mask (N,) of the held particles). See the module docstring."""
    mask, local = held(model, state, index, obj)
    n = int(mask.sum())
    if n < 4:
        raise ValueError(f"{obj.name} holds only {n} particles: too few to measure a volume")
    p = local[mask]
    s = model.spacing
    xz, owner, bottom, top, scale = _columns(obj, s / 4.0)
    q = torch.as_tensor(np.stack([xz[:, 0], np.zeros(len(xz)), xz[:, 1]], 1))
    pts = torch.as_tensor(p) * _SQUASH
    wet = (find_neighbors(q, pts, WET_REACH * s).counts() > 0).numpy()
    is_top = top_particles(p, s)
    nb = find_neighbors(q, pts[torch.as_tensor(is_top)], TOP_REACH * s)
    rows, ys = nb.rows(), torch.as_tensor(p[is_top, 1])[nb.col]
    total = torch.zeros(len(xz), dtype=torch.float64).index_add_(0, rows, ys).numpy()
    count = nb.counts().numpy()
    fallback = float(p[is_top, 1].mean())
    surf = np.where(count > 0, total / np.maximum(count, 1), fallback)
    surf = surf + 0.5 * math.sqrt(0.75) * nearest_spacing(p, s)
    depth = np.clip(surf[owner] - bottom, 0.0, top - bottom) * wet[owner]
    area = (s / 4.0) ** 2
    ml = float(depth.sum() * area * scale * 1e6)
    height = float(min(surf[wet].mean(), obj.rim_height)) if wet.any() else obj.floor_height
    return ml, height, mask
