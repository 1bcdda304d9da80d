"""A rigid object as the simulator and the volume code see it: solid mesh, wall, cavity, lip."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import torch
import trimesh

from .volume import ML_PER_M3, contains, height_for_volume, volume_below

MIN_WALL = 0.002
"""Thinnest wall the procedural models accept, m."""


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """A rigid object in its own frame (m, y up; containers stand on y = 0, opening up).

    Attributes:
      name: label (also the SDF grid's name).
      mesh: watertight solid, object frame, m.
      wall: thinnest wall of the solid, m (the SDF grid's anti-clipping thickness).
      cavity: watertight mesh of the space that holds liquid, up to the rim (its top face is
        the rim plane), or None for objects that hold no liquid.
      lip: (3,) object-frame pouring pivot on the rim for sources (the outer rim edge on the
        −x side), or None.
      anchors: named object-frame points, each (3,) m (e.g. ``"handle"``, ``"inlet"``).
    """

    name: str
    mesh: trimesh.Trimesh
    wall: float
    cavity: trimesh.Trimesh | None = None
    lip: np.ndarray | None = None
    anchors: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.mesh, trimesh.Trimesh) or not self.mesh.is_watertight:
            raise ValueError(f"{self.name}: mesh must be a watertight trimesh.Trimesh")
        if not (math.isfinite(self.wall) and self.wall > 0):
            raise ValueError(f"{self.name}: wall must be a positive thickness in m, "
                             f"got {self.wall}")
        cavity_ok = isinstance(self.cavity, trimesh.Trimesh) and self.cavity.is_watertight
        if self.cavity is not None and not cavity_ok:
            raise ValueError(f"{self.name}: cavity must be a watertight trimesh.Trimesh or None")
        if self.lip is not None:
            lip = np.asarray(self.lip, float).reshape(-1)
            if lip.shape != (3,) or not np.isfinite(lip).all():
                raise ValueError(f"{self.name}: lip must be a finite (3,) point, got {self.lip!r}")
            object.__setattr__(self, "lip", lip)
        anchors = {k: np.asarray(v, float).reshape(3) for k, v in self.anchors.items()}
        object.__setattr__(self, "anchors", anchors)

    # ------------------------------------------------------------------ liquid volumes

    @property
    def is_container(self) -> bool:
        return self.cavity is not None

    def _cavity(self) -> trimesh.Trimesh:
        if self.cavity is None:
            raise ValueError(f"{self.name} is not a container: it has no cavity that holds liquid")
        return self.cavity

    @property
    def rim_height(self) -> float:
        """Height of the rim plane (top of the cavity) in the object frame, m."""
        return float(self._cavity().bounds[1, 1])

    @property
    def floor_height(self) -> float:
        """Lowest point of the cavity in the object frame, m."""
        return float(self._cavity().bounds[0, 1])

    @cached_property
    def capacity_ml(self) -> float:
        """Liquid the container holds filled to the rim, ml."""
        return volume_below(self._cavity(), self.rim_height) * ML_PER_M3

    def volume_below_ml(self, height: float) -> float:
        """Liquid below the object-frame plane y = ``height`` (m) when upright, ml."""
        return volume_below(self._cavity(), height) * ML_PER_M3

    def height_for_volume(self, ml: float) -> float:
        """Object-frame height (m) of the flat liquid surface holding ``ml`` when upright.

        Raises:
          ValueError: for a negative volume or more than :attr:`capacity_ml`.
        """
        ml = float(ml)
        if not (math.isfinite(ml) and ml >= 0):
            raise ValueError(f"{self.name}: volume must be a finite value >= 0 ml, got {ml}")
        if ml > self.capacity_ml * (1 + 1e-9):
            raise ValueError(f"{self.name} holds at most {self.capacity_ml:.1f} ml; "
                             f"cannot fill {ml:.1f} ml")
        return height_for_volume(self._cavity(), min(ml, self.capacity_ml) / ML_PER_M3)

    def in_cavity(self, points) -> np.ndarray:
        """(N,) bool: object-frame points (N, 3) m inside the cavity (below the rim plane)."""
        return contains(self._cavity(), points)

    # ------------------------------------------------------------------ simulation

    def sdf(self, cell: float | None = None, cache_dir=None, dtype=torch.float32, **kwargs):
        """Signed distance grid of :attr:`mesh` (:func:`~liquidtwin.geometry.mesh_sdf_grid`).

        ``cell`` defaults to a quarter of the wall, coarsened (with a warning from the grid
        builder) only when that would exceed the node budget of a large object.
        """
        from .mesh_sdf import DEFAULT_MAX_NODES, mesh_sdf_grid

        max_nodes = kwargs.pop("max_nodes", DEFAULT_MAX_NODES)
        if cell is None:
            cell = self.wall / 4.0
            ext = self.mesh.extents
            while np.prod(np.ceil((ext + 6 * cell) / cell - 1e-9) + 1) > max_nodes:
                cell *= 1.05
        return mesh_sdf_grid(self.mesh, self.wall, cell=cell, name=self.name, cache_dir=cache_dir,
                             dtype=dtype, max_nodes=max_nodes, **kwargs)
