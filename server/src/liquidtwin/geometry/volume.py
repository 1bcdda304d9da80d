"""Volume of a closed mesh below a horizontal plane, its inverse, and point-in-mesh tests.

``volume_below`` is exact for a watertight mesh (SPEC §2): the faces are clipped by the
plane y = height (``trimesh.intersections.slice_faces_plane``) and the signed volumes of the
tetrahedra joining each remaining face to a point *on* the plane are summed. The cap that
would close the clipped mesh lies in the plane, so its tetrahedra are flat and contribute
nothing: no cap triangulation is needed, and holes of any shape in the cut are handled.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from . import _rays

ML_PER_M3 = 1e6


def _check_mesh(mesh, what: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(mesh, trimesh.Trimesh):
        raise TypeError(f"{what} must be a trimesh.Trimesh, got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise ValueError(f"{what} has no faces")
    return np.asarray(mesh.vertices, float), np.asarray(mesh.faces)


def volume_below(mesh: trimesh.Trimesh, height: float) -> float:
    """Volume of the closed ``mesh`` (object frame, m) below the plane y = ``height`` (m), m³.

    Heights below the mesh give 0, heights above it the whole volume.
    """
    height = float(height)
    if not math.isfinite(height):
        raise ValueError(f"height must be finite, got {height}")
    v, f = _check_mesh(mesh)
    if height >= v[:, 1].max():
        return float(_signed_volume(v[f], np.array([0.0, height, 0.0])))
    if height <= v[:, 1].min():
        return 0.0
    apex = np.array([0.0, height, 0.0])
    cv, cf, _ = trimesh.intersections.slice_faces_plane(
        v, f, plane_normal=np.array([0.0, -1.0, 0.0]), plane_origin=apex)
    if len(cf) == 0:
        return 0.0
    return float(_signed_volume(np.asarray(cv)[np.asarray(cf)], apex))


def _signed_volume(tri: np.ndarray, apex: np.ndarray) -> float:
    """Σ det(a − p, b − p, c − p) / 6 over triangles (T, 3, 3) with apex p (3,)."""
    a, b, c = tri[:, 0] - apex, tri[:, 1] - apex, tri[:, 2] - apex
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def height_for_volume(mesh: trimesh.Trimesh, volume: float, tol: float = 1e-7) -> float:
    """Height y (m) of the plane below which the closed ``mesh`` holds ``volume`` m³.

    Bisection on :func:`volume_below` (monotone in the height) to ``tol`` m.

    Raises:
      ValueError: for a negative or non-finite volume, or more than the mesh holds (the
        message states the capacity in ml).
    """
    volume = float(volume)
    if not (math.isfinite(volume) and volume >= 0):
        raise ValueError(f"volume must be a finite value >= 0 m³, got {volume}")
    v, _ = _check_mesh(mesh)
    lo, hi = float(v[:, 1].min()), float(v[:, 1].max())
    total = volume_below(mesh, hi)
    if volume > total * (1 + 1e-9):
        raise ValueError(f"asked for {volume * ML_PER_M3:.1f} ml but the volume holds at most "
                         f"{total * ML_PER_M3:.1f} ml (capacity)")
    if volume == 0:
        return lo
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if volume_below(mesh, mid) < volume:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def contains(mesh: trimesh.Trimesh, points) -> np.ndarray:
    """(N,) bool: which points (N, 3) m lie inside the closed ``mesh`` (ray parity, exact)."""
    v, f = _check_mesh(mesh)
    points = np.asarray(points, float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("points contain NaN or inf")
    return _rays.inside(v, f, points)
