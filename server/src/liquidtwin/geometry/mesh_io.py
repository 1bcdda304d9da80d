"""User meshes: load and repair OBJ/STL/PLY/GLB files, turn a container mesh into an ObjectModel.

``load_mesh`` reads any format trimesh reads, flattens a scene into one mesh (applying its
transforms), merges duplicate vertices, drops degenerate and duplicate faces, makes the
winding consistent and outward, and fills small holes. A mesh that is still open raises
:class:`MeshError` naming the file and counting the open edges: the simulator needs a
closed solid to tell inside from outside.

``container_from_mesh`` finds the space that holds liquid (see :mod:`._cavity` for the
exact definition: below the lowest point of the rim, open to the top, not solid) and
estimates the wall thickness when it is not given.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import trimesh

from . import _cavity, _rays
from .object_model import ObjectModel

MAX_VOXELS = 6_000_000


class MeshError(ValueError):
    """A mesh file or mesh that liquidtwin cannot use (unreadable, open, not a container)."""


def _edge_report(mesh: trimesh.Trimesh) -> tuple[int, int]:
    """(open edges, edges shared by more than two faces)."""
    if len(mesh.faces) == 0:
        return 0, 0
    _, counts = np.unique(np.sort(np.asarray(mesh.edges), axis=1), axis=0, return_counts=True)
    return int((counts == 1).sum()), int((counts > 2).sum())


def load_mesh(path, scale: float = 1.0) -> trimesh.Trimesh:
    """Read a mesh file (OBJ, STL, PLY, GLB/GLTF, …) as one watertight solid.

    Args:
      path: file path.
      scale: factor applied to the coordinates to get metres (0.001 for a file in mm).
    Returns:
      trimesh.Trimesh in the file's frame, m.
    Raises:
      MeshError: unreadable file, no triangles, non-finite coordinates, or a surface that is
        still open after repair (the message counts the open edges).
    """
    path = Path(path)
    scale = float(scale)
    if not (math.isfinite(scale) and scale > 0):
        raise MeshError(f"{path}: scale must be a positive number (metres per file unit), "
                        f"got {scale}")
    if not path.is_file():
        raise MeshError(f"{path}: no such mesh file")
    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as err:  # noqa: BLE001 - any reader failure is reported the same way
        raise MeshError(f"{path}: cannot read it as a mesh ({type(err).__name__}: {err})") from err
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MeshError(f"{path}: the file holds no triangles")
    if not np.isfinite(mesh.vertices).all():
        raise MeshError(f"{path}: the mesh has NaN or infinite vertex coordinates")
    mesh = trimesh.Trimesh(np.asarray(mesh.vertices, float) * scale, np.asarray(mesh.faces),
                           process=False)
    extent = float(mesh.extents.max())
    if extent > 5.0:
        warnings.warn(f"{path}: the mesh is {extent:.1f} m across; if the file is in mm pass "
                      f"scale=0.001", stacklevel=2)
    return repair(mesh, str(path))


def repair(mesh: trimesh.Trimesh, what: str = "mesh") -> trimesh.Trimesh:
    """Merge vertices, drop degenerate/duplicate faces, fill holes, orient faces outward.

    Returns a repaired copy; raises :class:`MeshError` when it is still not a closed solid.
    """
    m = mesh.copy()
    m.merge_vertices()
    m.update_faces(m.nondegenerate_faces())
    m.update_faces(m.unique_faces())
    m.remove_unreferenced_vertices()
    if not m.is_watertight:
        trimesh.repair.fill_holes(m)
    open_edges, shared = _edge_report(m)
    if open_edges or shared or not m.is_watertight:
        raise MeshError(f"{what}: the surface is not closed even after repair ({open_edges} open "
                        f"edges, {shared} edges shared by more than two faces); liquidtwin needs a "
                        f"watertight solid: close the holes in a mesh editor or export a solid")
    trimesh.repair.fix_winding(m)
    if not m.is_winding_consistent:
        raise MeshError(f"{what}: the faces cannot be oriented consistently "
                        f"(a non-orientable surface)")
    if m.volume < 0:
        m.invert()
    return m


def estimate_wall(mesh: trimesh.Trimesh, samples: int = 400, seed: int = 0) -> float:
    """Thin-wall thickness of a closed mesh, m: the 10th percentile of the distances from
    random surface points straight through the solid (along the inward normal) to the
    surface on the other side. Low percentiles pick the walls, not the rim or the base."""
    samples = max(32, min(samples, int(4e7 // max(1, len(mesh.faces)))))
    points, face = trimesh.sample.sample_surface(mesh, samples, seed=seed)
    inward = -np.asarray(mesh.face_normals)[face]
    start = points + 1e-7 * inward
    t = _rays.first_hit(start, inward, mesh.vertices, mesh.faces, t_min=1e-9)
    t = t[np.isfinite(t)]
    if len(t) == 0:
        raise MeshError("could not measure a wall thickness (no ray crossed the solid)")
    return float(np.percentile(t, 10))


def container_from_mesh(mesh: trimesh.Trimesh, name: str = "container",
                        wall: float | None = None) -> ObjectModel:
    """An :class:`ObjectModel` for a user's container mesh (object frame, m, opening up +y).

    The cavity is the space that would hold liquid poured in from above: not solid, below
    the lowest point of the rim (found to ~1/16 of the analysis voxel, wall/2), open to the
    top, so sealed voids do not count. Its mesh is exact: the container's own inner faces,
    clipped at the rim level and closed by the rim plane.

    Args:
      mesh: watertight solid (see :func:`load_mesh`).
      name: label for errors, logs and the SDF.
      wall: thinnest wall, m; estimated with :func:`estimate_wall` when None.
    Raises:
      MeshError: an open mesh, or ``"… is not a container …"`` when nothing would hold liquid
        (a solid sphere, a flat slab, a sealed box).
    """
    if not isinstance(mesh, trimesh.Trimesh) or not mesh.is_watertight:
        raise MeshError(f"{name}: needs a watertight trimesh.Trimesh "
                        f"(use load_mesh to read and repair files)")
    if wall is None:
        wall = estimate_wall(mesh)
    wall = float(wall)
    if not (math.isfinite(wall) and wall > 0):
        raise MeshError(f"{name}: wall must be a positive thickness in m, got {wall}")
    cell = wall / 2.0
    ext = mesh.extents + 4 * cell
    while np.prod(np.ceil(ext / cell)) > MAX_VOXELS:
        cell *= 1.1
    if cell > wall / 1.5:
        warnings.warn(f"{name}: analysing a {mesh.extents.max():.2f} m object with "
                      f"{cell * 1e3:.1f} mm voxels, coarser than its {wall * 1e3:.1f} mm walls; "
                      f"thin walls may leak", stacklevel=2)
    try:
        cavity, height = _cavity.find_cavity(mesh, cell, name)
    except _cavity.CavityError as err:
        raise MeshError(str(err)) from None
    v = np.asarray(mesh.vertices)
    rim = v[np.abs(v[:, 1] - height) <= 2 * wall + cell]
    rim = rim if len(rim) else v
    k = int(np.argmin(rim[:, 0]))
    near = rim[np.abs(rim[:, 0] - rim[k, 0]) <= wall]
    lip = np.array([rim[k, 0], near[:, 1].max(), rim[k, 2]])
    return ObjectModel(name, mesh, wall, cavity, lip, {})
