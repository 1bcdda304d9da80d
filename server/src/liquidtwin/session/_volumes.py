"""Counting the particles a container holds, fast enough for every frame.

The rule is :func:`liquidtwin.scenes.liquid_level.held` (probe points pushed half a wall
off the walls, then "is the probe inside the cavity?"). The exact cavity test casts a
vertical ray per particle through the cavity mesh — ~30 ms for 2k particles, more than a
whole simulation step. A session asks the same question every frame of the same mesh, so
it voxelises the cavity once (crossings counted per voxel column, exact at voxel centres)
and looks probes up in the voxels: O(N), ~0.1 ms. Probes sit at least half a wall inside
the cavity or outside it, and the voxels are a quarter wall wide, so the two tests can only
disagree for a probe within half a voxel diagonal of the cavity surface.
"""

from __future__ import annotations

import hashlib
import math
import time

import numpy as np
import torch

from ..geometry import ObjectModel, _rays
from ..scenes.liquid_level import held_probes

#: Largest voxel grid built per container (bool voxels).
MAX_VOXELS = 8_000_000


class CavityVoxels:
    """Occupancy of ``obj``'s cavity on a voxel grid in the object frame.

    Attributes:
      lo: (3,) object-frame corner of voxel (0, 0, 0), m. cell: voxel edge, m.
      occ: (nx, ny, nz) bool, voxel centre inside the cavity.
    """

    def __init__(self, obj: ObjectModel, cell: float | None = None):
        cavity = obj.cavity
        if cavity is None:
            raise ValueError(f"{obj.name} is not a container: it has no cavity")
        lo, hi = np.asarray(cavity.bounds, float)
        cell = obj.wall / 4.0 if cell is None else float(cell)
        while np.prod(np.ceil((hi - lo) / cell) + 2) > MAX_VOXELS:
            cell *= 1.25
        self.cell = cell
        self.lo = lo - cell
        shape = tuple(int(math.ceil(s)) + 2 for s in (hi - lo) / cell)
        self.occ = _rays.occupancy(np.asarray(cavity.vertices, float), np.asarray(cavity.faces),
                                   self.lo, cell, shape)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: object-frame points (N, 3) m whose voxel lies in the cavity."""
        idx = np.floor((np.asarray(points, float) - self.lo) / self.cell).astype(np.int64)
        ok = ((idx >= 0) & (idx < np.array(self.occ.shape))).all(1)
        out = np.zeros(len(idx), bool)
        i = idx[ok]
        out[ok] = self.occ[i[:, 0], i[:, 1], i[:, 2]]
        return out


def held_count_fast(model, state, index: int, obj: ObjectModel, voxels: CavityVoxels) -> int:
    """Particles container ``index`` holds, by :func:`held`'s rule with the voxelised cavity."""
    keep, probe, _ = held_probes(model, state, index, obj)
    return int((keep & voxels.contains(probe)).sum())


# ---------------------------------------------------------------------- model-based volumes
#: The session's mask grid is about this many blocks across (stride = width / this, ≥ 1 px).
BLOCKS_ACROSS = 80
#: A container counts as still (its cached ray casts reused) within this move, m / rad.
STILL_M, STILL_RAD = 5e-4, 2e-3
#: Share of the initial belief spread evenly over all bins (the rest sits on the stated fill).
PRIOR_FLOOR = 0.05
#: Most predict steps applied at once after masks that could not show a container's liquid.
MAX_PREDICT = 300


def _camera_key(camera, stride: int) -> str:
    """Digest of a camera's calibration and pose (and the stride): equal keys cast equal rays."""
    h = hashlib.sha1(f"{camera.width}x{camera.height}/{stride}".encode())
    for t in (camera.K, camera.distortion, camera.position, camera.rotation):
        h.update(np.ascontiguousarray(torch.as_tensor(t).detach().cpu().double().numpy()).tobytes())
    return h.hexdigest()[:16]


def _moved(a: np.ndarray, b: np.ndarray) -> bool:
    dq = abs(float(np.dot(a[3:], b[3:])))
    return bool(np.linalg.norm(a[:3] - b[:3]) > STILL_M or 2 * math.acos(min(1.0, dq)) > STILL_RAD)


class MaskVolumes:
    """Model-based volume of every container from the liquid masks (SPEC §5, thesis 5.1.3).

    Per container: a :class:`~liquidtwin.volumes.LevelTable` over the bins of the shipped
    learned transition (:func:`~liquidtwin.volumes.scaled_transition`: fractions of the
    session's liquid, cut at the capacity) and a :class:`~liquidtwin.volumes.VolumeFilter`
    whose belief starts on the spec's stated fill. Every mask: a predict step (one per
    engine frame with masks), then the likelihood of the mask downsampled to ~:data:`BLOCKS_ACROSS`
    blocks across, the other scene objects occluding. A mask that could not show this
    container's liquid at any volume (interior unseen, or liquid hidden behind the walls) is
    skipped; the next informative one first predicts once per mask frame missed (the
    transition is learned per mask frame). The filter reads only masks, poses and the camera.
    """

    def __init__(self, names, objects, containers, occluders, total_ml: float, spacing: float, fills: dict,
                 surface_offset_spacings: float | None = None, shift: float | None = None):
        from ..volumes import MIN_DEPTH_SPACINGS, SURFACE_OFFSET_SPACINGS, LevelTable, VolumeFilter, scaled_transition
        from ..volumes.hmm import SHIFT_SHARE
        self._shift = SHIFT_SHARE if shift is None else float(shift)
        if not (math.isfinite(self._shift) and 0 <= self._shift <= 1):
            raise ValueError(f"shift must be a share in [0, 1], got {shift}")
        off = (SURFACE_OFFSET_SPACINGS if surface_offset_spacings is None else float(surface_offset_spacings)) * spacing
        self._names = tuple(names)
        self._tables, self._filters, self._prior = {}, {}, {}
        for name in containers:
            obj = objects[self._names.index(name)]
            bins, T = scaled_transition(total_ml, obj.capacity_ml)
            self._tables[name] = LevelTable.create(obj, bins, min_depth=MIN_DEPTH_SPACINGS * spacing, surface_offset=off)
            self._filters[name] = VolumeFilter(bins, T)
            p = np.zeros(len(bins))
            p[int(np.argmin(np.abs(bins - float(fills.get(name, 0.0)))))] = 1.0
            self._prior[name] = (1 - PRIOR_FLOOR) * p + PRIOR_FLOOR / len(bins)
        self._occluders = [(objects[k].mesh, k) for k in occluders]
        self._rays = None                      # (camera key, pixel_rays)
        self._hits: dict = {}                  # "container|camera key" → (anchor pose, container_hits)
        self.last_ms = 0.0                     # wall time of the latest update, ms
        self.reset()

    def reset(self) -> None:
        self._belief: dict = {}
        self._anchor: dict = {}
        self._mask_frames = 0                  # engine frames that brought a mask
        self._last_frame = -1
        self._steps_at: dict = {}              # container → _mask_frames at its latest update

    def update(self, frame: int, camera, mask: np.ndarray, poses: np.ndarray) -> None:
        """Filter one (H, W) bool mask of ``camera`` taken at engine frame ``frame``, objects at
        ``poses`` (M, 7) (scene order).

        A container's ray casts are redone only when it moved more than :data:`STILL_M` /
        :data:`STILL_RAD` from the pose they were cast at (its *anchor*, kept in the
        checkpoint so that a restored session casts the same rays)."""
        from ..volumes import container_hits, downsample_mask, expected_masks, log_likelihood, pixel_rays
        start = time.perf_counter()
        stride = max(1, int(round(camera.width / BLOCKS_ACROSS)))
        ck = _camera_key(camera, stride)
        if self._rays is None or self._rays[0] != ck:
            self._rays = (ck, pixel_rays(camera, stride))
        rays = self._rays[1]
        obs = downsample_mask(mask, stride)
        if frame != self._last_frame:
            self._mask_frames, self._last_frame = self._mask_frames + 1, int(frame)
        for name, table in self._tables.items():
            k = self._names.index(name)
            pose = np.asarray(poses[k], float)
            akey = f"{name}|{ck}"
            anchor = self._anchor.get(akey)
            if anchor is None or _moved(anchor, pose):
                anchor = self._anchor[akey] = pose.copy()
            hit = self._hits.get(akey)
            if hit is None or not np.array_equal(hit[0], anchor):
                hit = self._hits[akey] = (anchor, container_hits(table.model, anchor, rays))
            occ = [(m, poses[j]) for m, j in self._occluders if j != k]
            e = expected_masks(table, pose, camera, stride, occluders=occ, fast=True, rays=rays, hits=hit[1])
            if not e.liquid.any():            # no volume would show liquid here: the mask says nothing
                continue
            filt = self._filters[name]
            b = self._belief.get(name)
            if b is None:
                b = filt.initial(self._prior[name])
            else:
                for _ in range(min(MAX_PREDICT, self._mask_frames - self._steps_at[name])):
                    b = filt.predict(b)
            self._belief[name] = filt.update(b, log_likelihood(e.liquid, e.interior, obs, fractions=e.fractions,
                                                                  shift=self._shift))
            self._steps_at[name] = self._mask_frames
        self.last_ms = 1e3 * (time.perf_counter() - start)

    def volumes(self) -> dict:
        """{container: posterior median ml, or None before a mask could first show its liquid}."""
        return {n: (self._filters[n].median(self._belief[n]) if n in self._belief else None) for n in self._tables}

    def state_dict(self) -> dict:
        return {"belief": {n: torch.as_tensor(b.copy()) for n, b in self._belief.items()},
                "steps_at": dict(self._steps_at), "mask_frames": self._mask_frames, "last_frame": self._last_frame,
                "anchor": {k: torch.as_tensor(a.copy()) for k, a in self._anchor.items()}}

    def load_state_dict(self, state: dict) -> None:
        self.reset()
        for n, b in state.get("belief", {}).items():
            if n in self._tables and tuple(b.shape) == self._filters[n].bins.shape:
                self._belief[n] = b.numpy().astype(np.float64)
                self._steps_at[n] = int(state["steps_at"][n])
        self._mask_frames = int(state.get("mask_frames", 0))
        self._last_frame = int(state.get("last_frame", -1))
        self._anchor = {k: a.numpy().astype(np.float64) for k, a in state.get("anchor", {}).items()}
