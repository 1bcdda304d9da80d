"""Expected liquid masks of a container for a set of candidate volumes (SPEC §5, thesis 5.1.3).

For a container (:class:`~liquidtwin.geometry.ObjectModel`) at a pose and a camera:

- The liquid holding v ml is the cavity below the **world-horizontal** plane y = h(v).
  :class:`LevelTable` gives h(v): upright containers use the exact bisection of
  :meth:`ObjectModel.height_for_volume` (precomputed once per bin); a tilted one samples
  the volume of the cavity below the tilted plane at ``_TILT_LEVELS`` levels, then bisects
  ``_BISECT_STEPS`` times inside the bracketing pair of levels per bin (about 0.3 s per
  frame for 61 bins; a tilt under 0.1 mrad counts as upright). Volumes above what the
  tilted cavity holds below its rim plane are placed as if the rim plane were closed
  (spilling is not modelled).
- Rays go from the camera centre through the **centres of stride × stride pixel blocks**
  (the image is downsampled by the integer ``stride``, the block (i, j) covers pixels
  [i·s, (i+1)·s) × [j·s, (j+1)·s); its ray passes through (u, v) = (j·s + (s−1)/2,
  i·s + (s−1)/2)). Lens distortion is removed with ``cv2.undistortPoints``.
- Every crossing of each ray with the cavity surface is found once per frame (brute-force
  Möller–Trumbore in NumPy, rays culled by the cavity's bounding box); the ray is inside the
  cavity between crossings 1–2, 3–4, …. Intersecting these intervals with the half-line
  below each candidate plane gives, for all K volumes at once, where the ray enters the
  liquid body (the cavity clipped at the surface plane).
- A block is **interior** when its ray enters the cavity before it hits any occluder (the
  container's own solid mesh — walls are opaque, as in the generator's masks — and any
  extra ``occluders``), and **expected liquid** for volume v when it enters the liquid body
  of v before it hits an occluder.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from ..geometry.volume import ML_PER_M3
from ._rays import _check_pose, crossings, pixel_rays, quat_matrix

#: Thinnest liquid layer of a particle model, in particle spacings (a pool shallower than
#: this covers part of the floor: :class:`LevelTable`). Calibrated on the 18 training pours of
#: ``python -m liquidtwin.volumes.learn`` (seeds 50000+, not the evaluation's) by
#: ``bench/volume_min_depth.py``: target RMSE 14.5 / 11.2 / 8.4 / 7.8 / 10.5 ml at 0.5 / 0.8 /
#: 1.2 / 1.6 / 2.4 spacings (settled puddles are a layer or two of particles deep).
MIN_DEPTH_SPACINGS = 1.6
#: How far below the level that holds v the liquid's visible surface lies, in particle spacings
#: (:class:`LevelTable` ``surface_offset``). 0: tried on 9 full-scene training pours of a cup
#: into the bowl (seeds 50000–50008) by ``bench/volume_surface_offset.py``, offsets 0.2–0.5 did
#: not lower the target's RMSE consistently (README, "Tracking and hidden state": volumes).
SURFACE_OFFSET_SPACINGS = 0.0
_TILT_LEVELS = 129
_BISECT_STEPS = 8                    # bracket (extent / 128) / 2⁸: ~1.5 µm for a 5 cm cavity
_UPRIGHT_COS = math.cos(1e-4)        # tilts below 0.1 mrad count as upright
_SAMPLES = 60_000                   # cavity sample points of the fast tilted heights
_EPS = 1e-7                          # m, ties between the cavity and the solid surfaces


def _plane_volume(cavity: trimesh.Trimesh, n: np.ndarray, s: float) -> float:
    """Volume (m³) of the closed ``cavity`` on the side n·p < s of the plane n·p = s."""
    apex = s * n
    v, f, _ = trimesh.intersections.slice_faces_plane(
        np.asarray(cavity.vertices, float), np.asarray(cavity.faces), plane_normal=-n,
        plane_origin=apex)
    if len(f) == 0:
        return 0.0
    tri = np.asarray(v)[np.asarray(f)] - apex
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)


@dataclass(frozen=True, eq=False)
class LevelTable:
    """Liquid surface heights of one container for fixed candidate volumes.

    A liquid cannot spread thinner than ``min_depth`` (a real puddle is a few mm deep; the
    simulated one is about one particle spacing): a volume v below ``pool_ml`` (what the
    cavity holds up to ``min_depth`` above its floor) is a pool of that depth covering the
    fraction v / pool_ml of the area the full pool would, at an unknown place
    (:attr:`fractions`; :func:`~liquidtwin.volumes.hmm.log_likelihood` places it where it
    best explains the mask). Without this a shallow pan's 20 ml would be expected as a 0.5 mm
    film over the whole floor and a real puddle (~10 % of the floor) would read 0 ml.

    Attributes:
      model: the container.
      volumes_ml: (K,) candidate volumes, ml, increasing, in [0, capacity].
      upright: (K,) object-frame surface heights y (m) when upright (exact bisection).
      min_depth: thinnest liquid layer, m (0: a flat film of any thickness).
      pool_ml: volume of the thinnest layer, ml. fractions: (K,) pool fraction covered (≤ 1).
      surface_offset: the visible surface lies this far (m) below the level that holds v, but
        never below the thinnest layer's: a pool of particles shows its top layer, whose centres
        sit below that level (the full 60 % partial cup pour at rest, an uncommitted diagnostic:
        232 ml fill the bowl to 17.0 mm, the top particle centres are at 15.5–16.2 mm, and the
        last frame's mask is likeliest at 198 ml).
    """

    model: object
    volumes_ml: np.ndarray
    upright: np.ndarray
    min_depth: float = 0.0
    pool_ml: float = 0.0
    fractions: np.ndarray | None = None
    surface_offset: float = 0.0

    @classmethod
    def create(cls, model, volumes_ml, min_depth: float = 0.0, surface_offset: float = 0.0) -> "LevelTable":
        vols = np.asarray(volumes_ml, float).reshape(-1)
        if len(vols) == 0 or not np.isfinite(vols).all():
            raise ValueError("volumes_ml must be a non-empty list of finite volumes in ml")
        if (np.diff(vols) <= 0).any():
            raise ValueError("volumes_ml must be strictly increasing")
        if not model.is_container:
            raise ValueError(f"{model.name} is not a container: it has no cavity")
        if vols[0] < 0 or vols[-1] > model.capacity_ml * (1 + 1e-9):
            raise ValueError(f"{model.name} holds 0 … {model.capacity_ml:.1f} ml; candidate "
                             f"volumes span {vols[0]:.1f} … {vols[-1]:.1f} ml")
        if not (math.isfinite(min_depth) and min_depth >= 0):
            raise ValueError(f"min_depth must be a finite depth >= 0 m, got {min_depth}")
        if not (math.isfinite(surface_offset) and surface_offset >= 0):
            raise ValueError(f"surface_offset must be a finite depth >= 0 m, got {surface_offset}")
        pool = 0.0
        if min_depth > 0:
            pool = min(model.volume_below_ml(model.floor_height + min_depth), model.capacity_ml)
        surface = np.maximum(vols, pool)
        frac = np.ones(len(vols)) if pool <= 0 else np.minimum(vols / pool, 1.0)
        return cls(model, vols, np.array([model.height_for_volume(v) for v in surface]),
                   float(min_depth), float(pool), frac, float(surface_offset))

    @property
    def surface_ml(self) -> np.ndarray:
        """(K,) volumes whose flat surface is drawn: ``volumes_ml``, at least ``pool_ml``."""
        return np.maximum(self.volumes_ml, self.pool_ml)

    def heights(self, pose, fast: bool = False) -> np.ndarray:
        """(K,) world heights y (m) of the flat surface for each volume, container at ``pose`` (7,).

        ``fast``: a tilted container's heights from a fixed sample of ~:data:`_SAMPLES` cavity
        points (the volume below a plane = the points below it × their share of the capacity;
        ~5 ms instead of ~0.3 s, heights within about a sample cell)."""
        h = self._level_heights(pose, fast)
        if self.surface_offset <= 0:
            return h
        # The thinnest layer's surface (the lowest; bins at or below pool_ml share it) is not lowered.
        floor = h[0] if self.pool_ml > 0 and self.volumes_ml[0] <= self.pool_ml else -np.inf
        return np.maximum(h - self.surface_offset, floor)

    def _level_heights(self, pose, fast: bool) -> np.ndarray:
        """(K,) world heights y (m) of the planes that hold :attr:`surface_ml` (:meth:`heights`
        before the surface offset)."""
        pose = _check_pose(pose)
        n = quat_matrix(pose[3:])[1]                  # world up in the object frame
        if n[1] >= _UPRIGHT_COS:
            return self.upright + pose[1]
        want = self.surface_ml
        if fast:
            proj = np.sort(self._samples() @ n)
            cum = (np.arange(len(proj)) + 0.5) * (self.model.capacity_ml / len(proj))
            return np.interp(want, np.r_[0.0, cum], np.r_[proj[0], proj]) + pose[1]
        cav = self.model.cavity
        proj = np.asarray(cav.vertices, float) @ n
        levels = np.linspace(proj.min(), proj.max(), _TILT_LEVELS)
        vol = np.maximum.accumulate([_plane_volume(cav, n, s) * ML_PER_M3 for s in levels])
        out = np.interp(want, vol, levels)
        for k, v in enumerate(want):                      # bisect inside the bracketing levels
            i = int(np.searchsorted(vol, v))
            if v <= 0 or i == 0 or i >= len(levels):
                continue
            lo, hi = levels[i - 1], levels[i]
            for _ in range(_BISECT_STEPS):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if _plane_volume(cav, n, mid) * ML_PER_M3 < v else (lo, mid)
            out[k] = 0.5 * (lo + hi)
        return out + pose[1]

    def _samples(self) -> np.ndarray:
        """(S, 3) object-frame cell centres inside the cavity (built once)."""
        pts = self.__dict__.get("_pts")
        if pts is None:
            lo, hi = np.asarray(self.model.cavity.bounds, float)
            cell = (np.prod(hi - lo) / _SAMPLES) ** (1 / 3)
            axes = [np.arange(lo[i] + cell / 2, hi[i], cell) for i in range(3)]
            pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
            pts = pts[self.model.in_cavity(pts)]
            object.__setattr__(self, "_pts", pts)
        return pts


@dataclass(frozen=True)
class ExpectedMasks:
    """Expected liquid masks on the downsampled image grid.

    Attributes:
      liquid: (K, h, w) bool, block expected to show liquid for each candidate volume.
      interior: (h, w) bool, blocks whose ray sees the cavity (only these are scored).
      heights: (K,) world surface heights y, m.
      stride: downsampling factor, px.
      fractions: (K,) share of each liquid mask the liquid covers, at an unknown place
        (:attr:`LevelTable.fractions`; 1: all of it).
    """

    liquid: np.ndarray
    interior: np.ndarray
    heights: np.ndarray
    stride: int
    fractions: np.ndarray | None = None


def container_hits(model, pose, rays, opaque: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The per-pose ray casts of :func:`expected_masks`: ((R, M) crossings with ``model``'s
    cavity, (R,) distance to its own solid — inf when ``opaque`` is False), m; ``rays`` as
    :func:`pixel_rays` returns them. Cache them while the container and camera stand still."""
    o, d, _ = rays
    cav = crossings(o, d, model.cavity, pose)
    own = crossings(o, d, model.mesh, pose)[:, 0] if opaque else np.full(len(d), np.inf)
    return cav, own


def expected_masks(table: LevelTable, pose, camera, stride: int = 4,
                   occluders=(), opaque: bool = True, fast: bool = False, rays=None,
                   hits=None) -> ExpectedMasks:
    """Expected liquid masks of ``table.model`` at ``pose`` (7,) for each of ``table.volumes_ml``.

    Args:
      camera: :class:`~liquidtwin.camera.Camera`. stride: downsampling factor (px, ≥ 1).
      occluders: extra (trimesh.Trimesh solid, pose (7,)) pairs that hide the container.
      opaque: the container's own walls hide what lies behind them (False: a glass container).
      fast: tilted heights from the cavity sample (:meth:`LevelTable.heights`).
      rays: ``pixel_rays(camera, stride)`` when the caller keeps them.
      hits: ``container_hits(table.model, pose, rays, opaque)`` when the caller keeps them.
    """
    model = table.model
    rays = pixel_rays(camera, stride) if rays is None else rays
    o, d, (h, w) = rays
    heights = table.heights(pose, fast=fast)
    cav, occ = container_hits(model, pose, rays, opaque) if hits is None else hits
    seen = np.nonzero(np.isfinite(cav[:, 0]) & (cav[:, 0] < occ - _EPS))[0]
    occ = occ.copy()
    for mesh, p in tuple(occluders):                          # only rays that reach the cavity
        occ[seen] = np.minimum(occ[seen], crossings(o, d[seen], mesh, p)[:, 0])
    n = cav.shape[1] // 2
    a, b = cav[:, 0:2 * n:2], cav[:, 1:2 * n:2]              # (R, n) inside intervals
    interior = np.isfinite(a[:, 0]) & (a[:, 0] < occ - _EPS)
    dy = d[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        tp = (heights[:, None] - o[1]) / dy[None, :]          # (K, R) plane crossing
    down = (dy < 0)[None, :, None]
    up = (dy > 0)[None, :, None]
    lo = np.where(down, np.maximum(a[None], tp[..., None]), a[None])
    hi = np.where(up, np.minimum(b[None], tp[..., None]), b[None])
    level = (dy == 0)[None, :, None] & (o[1] >= heights[:, None, None])   # horizontal ray above
    ok = (lo < hi) & np.isfinite(a)[None] & ~level
    entry = np.where(ok, lo, np.inf).min(-1)                  # (K, R)
    liquid = entry < occ[None] - _EPS
    return ExpectedMasks(liquid.reshape(-1, h, w), interior.reshape(h, w), heights, int(stride),
                         table.fractions)


def downsample_mask(mask: np.ndarray, stride: int) -> np.ndarray:
    """(H, W) bool observed mask → (H // s, W // s) bool: majority of each s × s block."""
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must be (H, W), got shape {mask.shape}")
    s = int(stride)
    h, w = mask.shape[0] // s, mask.shape[1] // s
    blocks = mask[:h * s, :w * s].reshape(h, s, w, s).astype(np.float32)
    return blocks.mean((1, 3)) > 0.5
