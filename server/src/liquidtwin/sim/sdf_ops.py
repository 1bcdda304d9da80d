"""Constructive edits of SDF grids: carve a hole (a leak), add a solid (a blockage).

Both are exact CSG on the sampled values (max(sdf, −cut) and min(sdf, solid)); the result
is again an :class:`SDFGrid` in the same object frame, so a model gains a leak or a plug by
swapping one entry of ``FluidModel.objects``. The edited shape must lie inside the grid's
box (checked), otherwise part of it would silently vanish.
"""

from __future__ import annotations

import numpy as np
import torch

from .sdf import SDFGrid


def cylinder_sdf(centre, axis, radius: float, half_length: float):
    """Analytic SDF of a solid capped cylinder (object frame): ``centre`` (3,) m, ``axis``
    (3,) direction, ``radius`` and ``half_length`` m. Returns fn(points (..., 3)) → (...)."""
    c = np.asarray(centre, float)
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    if not (radius > 0 and half_length > 0):
        raise ValueError(f"cylinder needs radius > 0 and half_length > 0, got {radius}, {half_length}")

    def fn(p: np.ndarray) -> np.ndarray:
        d = p - c
        along = d @ a
        radial = np.linalg.norm(d - along[..., None] * a, axis=-1) - radius
        q = np.stack([radial, np.abs(along) - half_length], -1)
        return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(-1), 0.0)

    return fn


def _nodes(grid: SDFGrid) -> np.ndarray:
    n = grid.values.shape
    o = grid.origin.detach().cpu().double().numpy()
    axes = [o[a] + grid.cell * np.arange(n[a]) for a in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1)


def _edited(grid: SDFGrid, new: np.ndarray, thickness: float, what: str) -> SDFGrid:
    values = torch.as_tensor(new, dtype=grid.values.dtype, device=grid.values.device)
    if bool(torch.equal(values, grid.values)):
        raise ValueError(f"{what} does not touch object {grid.name!r}: check its position (object frame, m)")
    return SDFGrid(values, grid.origin, grid.cell, thickness, grid.name)


def carve(grid: SDFGrid, cut) -> SDFGrid:
    """Remove the solid ``cut`` (fn of object-frame points (..., 3) → SDF) from the object."""
    p = _nodes(grid)
    old = grid.values.detach().cpu().double().numpy()
    return _edited(grid, np.maximum(old, -cut(p)), grid.thickness, "the cut")


def solidify(grid: SDFGrid, solid) -> SDFGrid:
    """Add the solid ``solid`` (fn of object-frame points → SDF) to the object; it must lie
    inside the grid's box (at least one cell away from its faces)."""
    p = _nodes(grid)
    s = solid(p)
    border = np.concatenate([s[[0, -1]].ravel(), s[:, [0, -1]].ravel(), s[:, :, [0, -1]].ravel()])
    if (border < grid.cell).any():
        raise ValueError(f"the added solid reaches the edge of object {grid.name!r}'s SDF grid")
    old = grid.values.detach().cpu().double().numpy()
    return _edited(grid, np.minimum(old, s), grid.thickness, "the added solid")
