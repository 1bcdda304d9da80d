"""ConvSDF: the particle–object layer of SPNets (thesis §8.2.2, SPEC §1).

Rigid objects are signed distance grids in their own frame, placed in the world by a 6-D
pose ``(tx, ty, tz, qx, qy, qz, qw)`` (translation in m, unit quaternion x-y-z-w as in
Foxglove/ROS; it is normalised here, so any non-zero quaternion is accepted).

``ConvSDF(X)_i = Σ_k w_k min_j SDF_j(p_i + k·dilation)`` over a small stencil. Trilinear
interpolation is ``torch.nn.functional.grid_sample``, so gradients with respect to particle
positions *and* object poses — rotation included — are exact autograd derivatives of the
interpolant (the original SPNets code got the rotation gradient wrong and fell back to
finite differences).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

POSE_DIM = 7


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) quaternions (x, y, z, w), any norm > 0 → (..., 3, 3) rotation matrices."""
    q = q / q.norm(dim=-1, keepdim=True)
    x, y, z, w = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    ], -1).reshape(q.shape[:-1] + (3, 3))


def quat_from_axis_angle(axis, angle) -> torch.Tensor:
    """Unit quaternion (x, y, z, w) for a rotation by ``angle`` rad about ``axis`` (3,)."""
    axis = torch.as_tensor(axis, dtype=torch.float64)
    angle = torch.as_tensor(angle, dtype=torch.float64)
    axis = axis / axis.norm()
    return torch.cat([axis * torch.sin(angle / 2), torch.cos(angle / 2).reshape(1)])


def check_poses(poses: torch.Tensor, n_objects: int) -> None:
    """Raise a clear ValueError unless ``poses`` is a finite (M, 7) tensor with usable quaternions."""
    if poses.dim() != 2 or poses.shape != (n_objects, POSE_DIM):
        raise ValueError(f"poses must be ({n_objects}, 7) (tx ty tz qx qy qz qw), got {tuple(poses.shape)}")
    if not bool(torch.isfinite(poses).all()):
        raise ValueError("object poses contain NaN or inf")
    if n_objects and bool((poses[:, 3:].norm(dim=-1) < 1e-8).any()):
        raise ValueError("object pose quaternion has zero norm")


def interpolate_poses(p0: torch.Tensor, p1: torch.Tensor, s: float) -> torch.Tensor:
    """Poses a fraction ``s`` ∈ [0, 1] of the way from p0 to p1 (M, 7): lerp + nlerp.

    nlerp is used on the short arc; steps are small (one frame split into pieces), where it
    matches slerp to second order.
    """
    q0 = p0[:, 3:] / p0[:, 3:].norm(dim=-1, keepdim=True)
    q1 = p1[:, 3:] / p1[:, 3:].norm(dim=-1, keepdim=True)
    sign = torch.where((q0 * q1).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(q0.dtype)
    q = q0 + (q1 * sign - q0) * s
    t = p0[:, :3] + (p1[:, :3] - p0[:, :3]) * s
    return torch.cat([t, q / q.norm(dim=-1, keepdim=True)], -1)


def cached_for(objects: tuple, key, make):
    """``make()`` made once for exactly these ``objects`` (by identity) and kept on the first
    one, so it lives as long as they do (a module-level cache would keep every session's
    grids alive). The entry holds the other objects, so their ids cannot be reused by new
    objects while it exists. No objects: made afresh."""
    if not objects:
        return make()
    k = (key, tuple(id(o) for o in objects))
    hit = objects[0]._cache.get(k)
    if hit is None:
        hit = (objects[1:], make())
        objects[0]._cache[k] = hit
    return hit[1]


@dataclass(frozen=True, eq=False)
class SDFGrid:
    """A signed distance field sampled on a regular grid in the object frame.

    Attributes:
      values: (nx, ny, nz) signed distance at node (i, j, k), m; negative inside material.
      origin: (3,) position of node (0, 0, 0) in the object frame, m.
      cell: node spacing, m.
      thickness: thinnest wall of the object, m; moves are split into pieces shorter than
        a third of it so particles never cross a wall (anti-clipping). The grid cell
        should be at most a quarter of it.
      name: label for errors and logs.
    """

    values: torch.Tensor
    origin: torch.Tensor
    cell: float
    thickness: float
    name: str = "object"
    _volume: torch.Tensor = field(init=False, repr=False)
    _extent: torch.Tensor = field(init=False, repr=False)
    _cache: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        v = torch.as_tensor(self.values)
        if v.dim() != 3 or min(v.shape) < 2:
            raise ValueError(f"SDF grid {self.name!r} must be 3-D with >= 2 nodes per axis, got {tuple(v.shape)}")
        if not bool(torch.isfinite(v).all()):
            raise ValueError(f"SDF grid {self.name!r} has non-finite values")
        if not bool((v < 0).any()):
            raise ValueError(f"SDF grid {self.name!r} has no inside (no negative value): degenerate object")
        if not (self.cell > 0 and self.thickness > 0):
            raise ValueError(f"SDF grid {self.name!r} needs cell > 0 and thickness > 0")
        object.__setattr__(self, "values", v)
        object.__setattr__(self, "origin", torch.as_tensor(self.origin, dtype=v.dtype).reshape(3))
        # grid_sample wants (N, C, D, H, W) with D ↔ z, H ↔ y, W ↔ x.
        object.__setattr__(self, "_volume", v.permute(2, 1, 0).contiguous()[None, None])
        object.__setattr__(self, "_extent", torch.tensor(v.shape, dtype=v.dtype) - 1)
        object.__setattr__(self, "_cache", {})

    def _converted(self, what: str, device, dtype) -> torch.Tensor:
        """``values`` (contiguous, (nx, ny, nz)), ``origin`` or the grid_sample ``volume`` on a
        device and dtype, converted once and kept: every collision piece samples the grid again."""
        key = (what, torch.device(device), dtype)
        out = self._cache.get(key)
        if out is None:
            src = {"volume": self._volume, "values": self.values, "origin": self.origin}[what]
            out = src.to(device=device, dtype=dtype).contiguous()
            self._cache[key] = out
        return out

    def to(self, device=None, dtype=None) -> "SDFGrid":
        return SDFGrid(self.values.to(device=device, dtype=dtype), self.origin.to(device=device, dtype=dtype),
                       self.cell, self.thickness, self.name)

    @property
    def bounding_radius(self) -> float:
        """Largest distance from the object origin to a grid corner, m."""
        if "radius" in self._cache:
            return self._cache["radius"]
        lo = self.origin
        hi = self.origin + self._extent.to(lo) * self.cell
        corners = torch.stack(torch.meshgrid(*[torch.stack([lo[a], hi[a]]) for a in range(3)], indexing="ij"), -1)
        self._cache["radius"] = float(corners.reshape(-1, 3).norm(dim=-1).max())
        return self._cache["radius"]

    def sample_local(self, p: torch.Tensor, lower_bound: bool = False) -> torch.Tensor:
        """SDF at object-frame points (..., 3), m → (...); outside the grid it grows with the distance to it.

        With ``lower_bound`` the result never exceeds the true distance to the object (by
        1-Lipschitz continuity and because the grid box contains the object); used to
        skip particles that cannot reach an object during a move.
        """
        shape = p.shape[:-1]
        p = p.reshape(-1, 3)
        vol = self._converted("volume", p.device, p.dtype)
        extent = self._extent.to(device=p.device, dtype=p.dtype)
        u = (p - self.origin.to(p)) / self.cell
        uc = torch.minimum(torch.maximum(u, torch.zeros_like(u)), extent)
        g = (2.0 * uc / extent - 1.0).reshape(1, 1, 1, -1, 3)
        val = F.grid_sample(vol, g, mode="bilinear", padding_mode="border", align_corners=True).reshape(-1)
        outside = ((u - uc) * self.cell).norm(dim=-1)
        if lower_bound:
            return torch.maximum(outside, val - outside).reshape(shape)
        return (val + outside).reshape(shape)

    def lower_bound_local(self, p: torch.Tensor) -> torch.Tensor:
        """A lower bound on the SDF at object-frame points (..., 3), m (see :meth:`sample_local`)."""
        return self.sample_local(p, lower_bound=True)


def _world_to_local(points: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
    """World points (..., 3) → frame of an object at pose (7,)."""
    R = quat_to_matrix(pose[3:])
    flat = (points.reshape(-1, 3) - pose[:3]) @ R  # R^T (p - t) for row vectors, one 2-D GEMM
    return flat.reshape(points.shape)


def min_sdf(points: torch.Tensor, objects, poses: torch.Tensor) -> torch.Tensor:
    """min_j SDF_j at world points (..., 3) for objects at poses (M, 7) → (...), m.

    With no objects the distance is +inf everywhere (nothing to collide with).
    """
    if len(objects) == 0:
        return torch.full(points.shape[:-1], float("inf"), dtype=points.dtype, device=points.device)
    vals = [obj.sample_local(_world_to_local(points, poses[j])) for j, obj in enumerate(objects)]
    return torch.stack(vals, 0).min(0).values if len(vals) > 1 else vals[0]


def conv_sdf(points: torch.Tensor, objects, poses: torch.Tensor, offsets: torch.Tensor,
             weights: torch.Tensor, dilation: float) -> torch.Tensor:
    """ConvSDF layer: ``out[i, c] = Σ_k weights[c, k] · min_j SDF_j(p_i + offsets[k]·dilation)``.

    Args:
      points: (N, 3) particle positions, m.
      objects: sequence of M :class:`SDFGrid`.
      poses: (M, 7) object poses.
      offsets: (K, 3) stencil cell offsets (dimensionless).
      weights: (C, K) stencil weights.
      dilation: spacing of stencil cells, m.
    Returns:
      (N, C).
    """
    pts = points[:, None, :] + offsets.to(points)[None] * dilation  # (N, K, 3)
    return torch.mm(min_sdf(pts, objects, poses), weights.to(points).T)


# Stencil for collisions: centre + ±x, ±y, ±z. Row 0 of the weights reads the SDF value
# (ConvSDF_R with w = 1), rows 1–3 are central differences (ConvSDF_X/Y/Z, w = −1, 0, +1).
COLLISION_OFFSETS = torch.tensor([[0, 0, 0], [-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]],
                                 dtype=torch.float64)
COLLISION_WEIGHTS = torch.tensor([[1, 0, 0, 0, 0, 0, 0],
                                  [0, -1, 1, 0, 0, 0, 0],
                                  [0, 0, 0, -1, 1, 0, 0],
                                  [0, 0, 0, 0, 0, -1, 1]], dtype=torch.float64)


def push_out(points: torch.Tensor, objects, poses: torch.Tensor, collision_distance: float,
             dilation: float) -> torch.Tensor:
    """One collision fix: ``P' = P + ReLU(c − SDF(P)) · n̂`` with n̂ the normalised SDF gradient.

    Args:
      points: (N, 3) m. objects/poses: as :func:`conv_sdf`.
      collision_distance: particles are kept this far outside surfaces, m.
      dilation: finite-difference half step for the normal, m.
    Returns:
      (N, 3) corrected positions.
    """
    if len(objects) == 0:
        return points
    out = conv_sdf(points, objects, poses, COLLISION_OFFSETS, COLLISION_WEIGHTS, dilation)
    depth = F.relu(collision_distance - out[:, 0])
    normal = F.normalize(out[:, 1:], dim=-1, eps=1e-12)
    return points + depth[:, None] * normal


def sweep_bound(objects, p0: torch.Tensor, p1: torch.Tensor) -> torch.Tensor:
    """(M,) upper bound on how far any point of each object moves from pose p0 to p1, m."""
    if len(objects) == 0:
        return torch.zeros(0)
    q0 = p0[:, 3:] / p0[:, 3:].norm(dim=-1, keepdim=True)
    q1 = p1[:, 3:] / p1[:, 3:].norm(dim=-1, keepdim=True)
    sign = torch.where((q0 * q1).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(q0.dtype)
    # 4·asin(|Δq|/2) is the rotation angle, accurate near zero (acos of the dot is not).
    angle = 4 * torch.asin(((q1 * sign - q0).norm(dim=-1) / 2).clamp(max=1.0))
    radius = torch.tensor([o.bounding_radius for o in objects], dtype=p0.dtype, device=p0.device)
    return ((p1[:, :3] - p0[:, :3]).norm(dim=-1) + radius * angle).detach()
