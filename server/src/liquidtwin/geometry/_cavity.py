"""Find the liquid-holding cavity of a user's container mesh.

Definition used (container upright, opening up, one liquid level): the cavity is the space
that is not solid, lies below the highest level H at which some free space is still cut
off from the outside, and is open to the outside above H (so sealed voids do not count).
In words: pour liquid in from above and it stays there up to H; above H it spills over the
lowest point of the rim.

How it is computed:

1. Voxel centres are classified solid/free exactly by ray parity along vertical lines.
2. For a level (the top layer of voxel centres allowed to hold liquid), free voxels at or
   below it are flooded from the sides and bottom of the grid; free voxels the flood does
   not reach, yet that connect to the outside through the full free space, are trapped.
3. The highest such level is found by a coarse scan and bisection, then refined between
   two voxel layers by shifting the grid vertically (rim found to ~1/16 voxel).
4. The cavity *mesh* is exact, not voxels: the solid's faces clipped at H whose outer side
   faces the trapped region, turned inside out, closed by fans over the cut at y = H
   (fans are exact for volume and winding even for a non-convex rim).
"""

from __future__ import annotations

import numpy as np
import trimesh

from . import _rays

MIN_CAVITY_M3 = 1e-6     # 1 ml: less than this is not a container


class CavityError(ValueError):
    pass


def _propagate(free: np.ndarray, reached: np.ndarray, axis: int) -> np.ndarray:
    """Spread ``reached`` along runs of free voxels parallel to ``axis``."""
    f = np.moveaxis(free, axis, -1)
    r = np.moveaxis(reached, axis, -1)
    n = f.shape[-1]
    lines, rl = f.reshape(-1, n), r.reshape(-1, n)
    key = np.arange(len(lines))[:, None] * (n + 1) + np.cumsum(~lines, axis=1)
    hit = np.zeros(len(lines) * (n + 1), bool)
    hit[key[rl]] = True
    return np.moveaxis((lines & hit[key]).reshape(f.shape), -1, axis)


def _flood(free: np.ndarray, top_open: bool) -> np.ndarray:
    """Free voxels connected (6-neighbours) to the grid's sides and bottom (and top if open)."""
    seeds = np.zeros_like(free)
    seeds[[0, -1], :, :] = True
    seeds[:, :, [0, -1]] = True
    seeds[:, 0, :] = True
    if top_open:
        seeds[:, -1, :] = True
    reached = seeds & free
    count = -1
    while int(reached.sum()) != count:
        count = int(reached.sum())
        for axis in (0, 2, 1):
            reached = _propagate(free, reached, axis)
    return reached


class _Grid:
    """Voxels of a mesh whose layer centres sit at y = top - k·cell (top a chosen level)."""

    def __init__(self, v, f, lo_xz, shape_xz, cell, bottom, top):
        n_below = int(np.ceil((top - bottom) / cell)) + 2
        self.cell, self.top = cell, top
        self.lo = np.array([lo_xz[0], top - (n_below - 0.5) * cell, lo_xz[1]])
        self.ny_top = n_below                                     # layers at or below `top`
        self.v, self.f, self.shape_xz = v, f, shape_xz

    def solid(self, extra_layers: int) -> np.ndarray:
        shape = (self.shape_xz[0], self.ny_top + extra_layers, self.shape_xz[1])
        return _rays.occupancy(self.v, self.f, self.lo, self.cell, shape)


def _trapped(solid_full: np.ndarray, layers: int, open_all: np.ndarray | None = None) -> np.ndarray:
    """Trapped free voxels in layers [0, layers) of a full-height solid grid.

    ``open_all``: free voxels connected to the outside through the whole grid (computed when
    not given); trapped voxels must belong to it, so sealed voids never count.
    """
    free = ~solid_full
    if open_all is None:
        open_all = _flood(free, top_open=True)
    sub = free[:, :layers, :]
    return sub & ~_flood(sub, top_open=False) & open_all[:, :layers, :]


_SHIFT = 0.381966   # grid offset in cells: keeps voxel centres off round-numbered flat faces


def _holds(solid: np.ndarray, layers: int, open_all: np.ndarray, min_count: int) -> bool:
    """Does liquid up to the top of layer ``layers - 1`` stay in? Some free space must be
    trapped, and most of what the level below trapped must still be (else it spilled and
    only small pockets, e.g. between voxels of a flat rim, remain)."""
    now = _trapped(solid, layers, open_all)
    if now.sum() < min_count:
        return False
    below = _trapped(solid, layers - 1, open_all).sum() if layers > 1 else 0
    return now[:, :layers - 1, :].sum() >= 0.5 * below


def find_cavity(mesh: trimesh.Trimesh, cell: float, name: str):
    """(cavity mesh, rim height H m) of a watertight container mesh; CavityError if none."""
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    lo, hi = v.min(0) - (2 + _SHIFT) * cell, v.max(0) + (2 + _SHIFT) * cell
    shape_xz = tuple(int(s) for s in np.ceil((hi[[0, 2]] - lo[[0, 2]]) / cell))
    lo_xz = lo[[0, 2]]
    base = _Grid(v, f, lo_xz, shape_xz, cell, lo[1], hi[1])
    solid = base.solid(extra_layers=1)
    open_all = _flood(~solid, top_open=True)
    ny = solid.shape[1]
    min_count = max(8, int(MIN_CAVITY_M3 / cell**3))

    # coarse scan from the top, then bisection up to the first level that spills
    step = max(1, ny // 24)
    found = next((n for n in range(ny, 0, -step) if _holds(solid, n, open_all, min_count)), None)
    if found is None:
        raise CavityError(f"{name} is not a container: no space below any level holds liquid "
                          f"(a closed solid, a flat slab, or an open shell?)")
    good, bad = found, min(found + step, ny + 1)
    while bad - good > 1:
        mid = (good + bad) // 2
        good, bad = (mid, bad) if _holds(solid, mid, open_all, min_count) else (good, mid)
    level = base.lo[1] + (good - 0.5) * cell          # centre of the top trapped layer
    # refine: shift the grid so the top layer's centre sits at level + s, s in [0, cell)
    lo_s, hi_s = 0.0, cell
    for _ in range(4):
        s = 0.5 * (lo_s + hi_s)
        g = _Grid(v, f, lo_xz, shape_xz, cell, lo[1], level + s)
        sol = g.solid(extra_layers=int(np.ceil((hi[1] - level - s) / cell)) + 1)
        if _holds(sol, g.ny_top, _flood(~sol, top_open=True), min_count):
            lo_s = s
        else:
            hi_s = s
    height = level + lo_s
    region = _trapped(solid, good, open_all)
    cavity = _cavity_mesh(v, f, height, region, base.lo, cell, ~solid[:, :good, :], name)
    return cavity, height


def _cavity_mesh(v, f, height, region, grid_lo, cell, free, name) -> trimesh.Trimesh:
    apex = np.array([0.0, height, 0.0])
    cv, cf, _ = trimesh.intersections.slice_faces_plane(
        v, f, plane_normal=np.array([0.0, -1.0, 0.0]), plane_origin=apex)
    cv, cf = np.asarray(cv), np.asarray(cf)
    tri = cv[cf]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(normal, axis=1)
    ok = area > 1e-14
    cf, tri, normal = cf[ok], tri[ok], normal[ok] / area[ok, None]
    q = tri.mean(1) + 0.3 * cell * normal
    idx = np.floor((q - grid_lo) / cell).astype(int)
    shape = np.array(region.shape)
    offsets = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cand = np.clip(idx[:, None, :] + offsets[None], 0, shape - 1)          # (F, 27, 3)
    centre = grid_lo + (cand + 0.5) * cell
    d2 = ((centre - q[:, None, :]) ** 2).sum(-1)
    is_free = free[cand[..., 0], cand[..., 1], cand[..., 2]]
    d2 = np.where(is_free, d2, np.inf)
    best = np.argmin(d2, axis=1)
    pick = cand[np.arange(len(cand)), best]
    inner = np.isfinite(d2.min(1)) & region[pick[:, 0], pick[:, 1], pick[:, 2]]
    if not inner.any():
        raise CavityError(f"{name}: found a cavity but none of the surface faces it")
    shell = trimesh.Trimesh(cv, cf[inner][:, ::-1], process=True)
    faces = np.asarray(shell.faces)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(directed, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = directed[counts[inv.reshape(-1)] == 1]
    verts = np.asarray(shell.vertices)
    if len(boundary) == 0 or np.abs(verts[boundary.reshape(-1), 1] - height).max() > 1e-6:
        raise CavityError(f"{name}: could not separate the inside of the container from its "
                          f"outside (walls thinner than the {cell * 1e3:.2f} mm analysis voxels? "
                          f"pass wall=...)")
    comp = _components(boundary, len(verts))
    labels = np.unique(comp[boundary[:, 0]])
    loop_of = comp[boundary[:, 0]]
    centres = np.stack([verts[np.unique(boundary[loop_of == c])].mean(0) for c in labels])
    centres[:, 1] = height
    centre_id = len(verts) + np.searchsorted(labels, comp[boundary[:, 0]])
    cap = np.stack([boundary[:, 1], boundary[:, 0], centre_id], 1)
    mesh = trimesh.Trimesh(np.concatenate([verts, centres]), np.concatenate([faces, cap]),
                           process=True)
    if not (mesh.is_watertight and mesh.is_winding_consistent) or mesh.volume <= 0:
        raise CavityError(f"{name}: the cavity surface did not close (open edges at the rim); "
                          f"is the mesh upright with the opening towards +y?")
    return mesh


def _components(edges: np.ndarray, n: int) -> np.ndarray:
    """Connected-component label (n,) of each vertex under the given edges (union-find)."""
    parent = np.arange(n)

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in edges:
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[ra] = rb
    return np.array([root(i) for i in range(n)])
