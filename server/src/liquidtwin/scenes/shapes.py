"""Analytic signed distance functions of simple containers, sampled to :class:`SDFGrid` s.

Used for the demo scene and as independent references in tests (the grid is trilinear, the
analytic function is exact). Every function takes object-frame points (..., 3) in m and
returns (...) signed distances, negative inside material. Containers stand on y = 0 with
their opening up (+y). Shells are CSG (max(outer, −cavity)), exact in sign and a close
bound on distance. Trimesh-based models come with the scenes work.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from ..sim.sdf import SDFGrid


def box(p: np.ndarray, half, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Solid axis-aligned box with half extents ``half`` (3,) m."""
    q = np.abs(p - np.asarray(centre)) - np.asarray(half)
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(-1), 0.0)


def sphere(p: np.ndarray, radius: float, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    return np.linalg.norm(p - np.asarray(centre), axis=-1) - radius


def cylinder(p: np.ndarray, radius: float, y0: float, y1: float) -> np.ndarray:
    """Solid capped cylinder about the y axis from y0 to y1."""
    r = np.linalg.norm(p[..., [0, 2]], axis=-1) - radius
    y = np.abs(p[..., 1] - 0.5 * (y0 + y1)) - 0.5 * (y1 - y0)
    d = np.stack([r, y], -1)
    return np.linalg.norm(np.maximum(d, 0.0), axis=-1) + np.minimum(d.max(-1), 0.0)


def open_box(p, inner_half_xz, height: float, wall: float) -> np.ndarray:
    """Open-top rectangular basin: inner size 2·inner_half_xz (2,) × height, walls ``wall`` m."""
    hx, hz = inner_half_xz
    outer = box(p, (hx + wall, 0.5 * (height + wall), hz + wall), (0, 0.5 * (height + wall), 0))
    cavity = box(p, (hx, height, hz), (0, wall + height, 0))
    return np.maximum(outer, -cavity)


def sealed_box(p, inner_half, wall: float) -> np.ndarray:
    """Closed box (a cavity fully enclosed by walls ``wall`` m), centred on the origin."""
    inner_half = np.asarray(inner_half, float)
    return np.maximum(box(p, inner_half + wall), -box(p, inner_half))


def cup(p, radius: float, height: float, wall: float) -> np.ndarray:
    """Open-top cylindrical cup: inner radius ``radius``, inner depth ``height - wall``."""
    outer = cylinder(p, radius + wall, 0.0, height)
    cavity = cylinder(p, radius, wall, 2.0 * height)
    return np.maximum(outer, -cavity)


def bowl(p, radius: float, wall: float) -> np.ndarray:
    """Hemispherical bowl of inner radius ``radius`` resting on y = 0, open at y = radius + wall."""
    c = np.array([0.0, radius + wall, 0.0])
    shell = np.abs(np.linalg.norm(p - c, axis=-1) - (radius + 0.5 * wall)) - 0.5 * wall
    return np.maximum(shell, p[..., 1] - c[1])


def sample_grid(fn, lo, hi, cell: float, thickness: float, name: str, dtype=torch.float32) -> SDFGrid:
    """Sample ``fn`` on grid nodes covering [lo, hi] (m) at spacing ``cell`` (m)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    n = np.ceil((hi - lo) / cell).astype(int) + 1
    axes = [lo[a] + cell * np.arange(n[a]) for a in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    return SDFGrid(torch.as_tensor(fn(pts), dtype=dtype), torch.as_tensor(lo, dtype=dtype), float(cell),
                   float(thickness), name)


def _grid(fn, half_xz: float, height: float, wall: float, name: str, cell: float | None = None) -> SDFGrid:
    cell = wall / 4.0 if cell is None else cell
    m = 3 * cell
    return sample_grid(fn, (-half_xz - m, -m, -half_xz - m), (half_xz + m, height + m, half_xz + m),
                       cell, wall, name)


def cup_grid(radius=0.04, height=0.10, wall=0.003, cell=None) -> SDFGrid:
    """SDF grid of :func:`cup` (defaults: 8 cm wide, 10 cm tall, 3 mm walls)."""
    return _grid(lambda p: cup(p, radius, height, wall), radius + wall, height, wall, "cup", cell)


def bowl_grid(radius=0.08, wall=0.003, cell=None) -> SDFGrid:
    """SDF grid of :func:`bowl` (default 16 cm wide, 3 mm walls)."""
    return _grid(lambda p: bowl(p, radius, wall), radius + wall, radius + wall, wall, "bowl", cell)


def open_box_grid(inner_half_xz=(0.05, 0.05), height=0.1, wall=0.003, cell=None) -> SDFGrid:
    hx, hz = inner_half_xz
    cell = wall / 4.0 if cell is None else cell
    m = 3 * cell
    return sample_grid(lambda p: open_box(p, inner_half_xz, height, wall),
                       (-hx - wall - m, -m, -hz - wall - m), (hx + wall + m, height + wall + m, hz + wall + m),
                       cell, wall, "box")


def sealed_box_grid(inner_half=(0.03, 0.03, 0.03), wall=0.003, cell=None) -> SDFGrid:
    cell = wall / 4.0 if cell is None else cell
    e = np.asarray(inner_half) + wall + 3 * cell
    return sample_grid(lambda p: sealed_box(p, inner_half, wall), -e, e, cell, wall, "sealed_box")


def floor_grid(half_xz=1.0, depth=0.05, cell=0.02) -> SDFGrid:
    """A thick slab whose top face is y = 0 (catches whatever is spilled)."""
    return sample_grid(lambda p: box(p, (half_xz, 0.5 * depth, half_xz), (0, -0.5 * depth, 0)),
                       (-half_xz - 2 * cell, -depth - 2 * cell, -half_xz - 2 * cell),
                       (half_xz + 2 * cell, 2 * cell, half_xz + 2 * cell), cell, depth, "floor")


def cup_mesh(radius: float = 0.04, height: float = 0.10, wall: float = 0.003, sections: int = 64) -> trimesh.Trimesh:
    """Triangle mesh of :func:`cup`'s shape (inner radius, total height, wall, m): a
    thin-walled cup revolved about y, standing on y = 0, open at the top; outward normals."""
    r, h, w = radius, height, wall
    profile = np.array([[0, 0], [r + w, 0], [r + w, h], [r, h], [r, w], [0, w]])
    mesh = trimesh.creation.revolve(profile[::-1], sections=sections)  # about z
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    if mesh.volume < 0:
        mesh.invert()
    return mesh
