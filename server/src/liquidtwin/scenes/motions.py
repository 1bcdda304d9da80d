"""Scripted 6-D pose trajectories for the thesis's motions (float64 numpy, y up, SI).

A motion is built from eased keyframes: a :class:`Profile` maps time (s) to a scalar or a
vector by holding each keyframe value and blending between consecutive ones with a cosine
ease (zero velocity at every keyframe, as a robot arm's point-to-point moves). A
:class:`PivotMotion` turns an angle profile and a pivot path into poses: the object rotates
by ``angle(t)`` about a fixed object-frame ``axis`` through the object-frame point ``pivot``,
which itself travels along ``path(t)`` in the world::

    x_world = R(axis, angle(t)) (x_local − pivot) + path(t)

Poses are (7,) arrays (tx, ty, tz, qx, qy, qz, qw), object → world.

Thesis motions (ch. 4.2.1): *partial* — tilt slightly past horizontal, hold 2 s, return
upright; *hold* — tilt slightly past horizontal and stay; *dump* — tilt quickly to nearly
vertical and stay. Ch. 8.3: plate tilts, ladle scoop-and-pour, a catching cup sliding under a
stream; ch. 7.4: a container tilting to feed a pipe junction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

IDENTITY = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])

#: Thesis pour trajectories: (tilt in degrees, time to tilt s, hold s or None = stay, return s).
POUR_KINDS = {
    "partial": (100.0, 2.5, 2.0, 2.0),
    "hold": (100.0, 2.5, None, 0.0),
    "dump": (160.0, 1.2, None, 0.0),
}


def quat_axis_angle(axis, angle: float) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation by ``angle`` rad about ``axis`` (3,)."""
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis)
    return np.concatenate([axis * math.sin(angle / 2.0), [math.cos(angle / 2.0)]])


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w) → (..., 3, 3) rotation matrices."""
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    ], -1).reshape(q.shape[:-1] + (3, 3))


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of (x, y, z, w) quaternions (rotation b, then a)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose a ∘ b (apply b, then a): both (7,) object → parent."""
    return np.concatenate([quat_matrix(a[3:]) @ b[:3] + a[:3], quat_multiply(a[3:], b[3:])])


def transform(pose: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Object-frame points (..., 3) → world under ``pose`` (7,)."""
    return np.asarray(p, float) @ quat_matrix(pose[3:]).T + pose[:3]


def _ease(s: float) -> float:
    return 0.5 - 0.5 * math.cos(math.pi * min(max(s, 0.0), 1.0))


@dataclass(frozen=True)
class Profile:
    """Piecewise cosine-eased keyframes: ``times`` (K,) s increasing, ``values`` (K, D)."""

    times: tuple[float, ...]
    values: tuple[tuple[float, ...], ...]

    @staticmethod
    def of(*keys) -> "Profile":
        """``Profile.of((t0, v0), (t1, v1), …)`` with scalar or vector values."""
        if not keys:
            raise ValueError("a profile needs at least one keyframe")
        times = tuple(float(t) for t, _ in keys)
        if any(b < a for a, b in zip(times, times[1:])):
            raise ValueError(f"keyframe times must not decrease: {times}")
        values = tuple(tuple(np.atleast_1d(np.asarray(v, float)).tolist()) for _, v in keys)
        if len({len(v) for v in values}) != 1:
            raise ValueError("all keyframe values must have the same length")
        return Profile(times, values)

    def __call__(self, t: float) -> np.ndarray:
        ts, vs = self.times, np.asarray(self.values)
        if t <= ts[0]:
            return vs[0].copy()
        for k in range(1, len(ts)):
            if t < ts[k]:
                f = _ease((t - ts[k - 1]) / (ts[k] - ts[k - 1]))
                return vs[k - 1] + f * (vs[k] - vs[k - 1])
        return vs[-1].copy()

    @property
    def end(self) -> float:
        return self.times[-1]


@dataclass(frozen=True)
class PivotMotion:
    """Rotation by ``angle(t)`` (rad) about object-frame ``axis`` through object-frame
    ``pivot`` (3,) m, with the pivot at world position ``path(t)`` (3,) m, after an optional
    fixed ``base`` orientation quaternion (object frame → pre-rotation frame)."""

    pivot: tuple[float, float, float]
    axis: tuple[float, float, float]
    angle: Profile
    path: Profile
    base: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    def __call__(self, t: float) -> np.ndarray:
        q = quat_multiply(quat_axis_angle(self.axis, float(self.angle(t)[0])), np.asarray(self.base, float))
        rot = quat_matrix(q)
        return np.concatenate([self.path(t) - rot @ np.asarray(self.pivot, float), q])

    @property
    def end(self) -> float:
        return max(self.angle.end, self.path.end)


@dataclass(frozen=True)
class Static:
    """An object that does not move: ``pose`` (7,)."""

    pose: tuple[float, ...] = tuple(IDENTITY)

    def __call__(self, t: float) -> np.ndarray:
        return np.asarray(self.pose, float)

    @property
    def end(self) -> float:
        return 0.0


def pour(kind: str, lip_local, lip_world, *, axis=(0.0, 0.0, 1.0), start: float = 0.5,
         tilt_deg: float | None = None, speed: float = 1.0) -> PivotMotion:
    """A thesis pour (``"partial"``, ``"hold"`` or ``"dump"``) about the lip.

    Args:
      lip_local: (3,) pouring lip in the source's frame, m; it stays at ``lip_world`` (3,).
      axis: rotation axis in the object frame; +z tips the opening towards −x.
      start: time the tilt begins, s. ``tilt_deg`` overrides the kind's angle.
      speed: > 1 shortens every phase by that factor.
    """
    if kind not in POUR_KINDS:
        raise ValueError(f"unknown pour {kind!r}; choose from {sorted(POUR_KINDS)}")
    if not speed > 0:
        raise ValueError(f"speed must be > 0, got {speed}")
    angle, t_tilt, t_hold, t_back = POUR_KINDS[kind]
    angle = math.radians(angle if tilt_deg is None else tilt_deg)
    t_tilt, t1 = t_tilt / speed, start + t_tilt / speed
    keys = [(0.0, 0.0), (start, 0.0), (t1, angle)]
    if t_hold is not None:
        t2 = t1 + t_hold / speed
        keys += [(t2, angle), (t2 + t_back / speed, 0.0)]
    return PivotMotion(tuple(lip_local), tuple(axis), Profile.of(*keys), Profile.of((0.0, lip_world)))


def plate_tilt(target: int, *, n_targets: int = 8, tilt_deg: float = 12.0, start: float = 1.0,
               t_tilt: float = 1.5, centre=(0.0, 0.0, 0.0)) -> PivotMotion:
    """Tilt a plate about its centre so its surface falls towards target ``target`` of
    ``n_targets`` placed evenly around it (target k at azimuth 2πk/n from +x)."""
    if not 0 <= target < n_targets:
        raise ValueError(f"target must be in 0..{n_targets - 1}, got {target}")
    phi = 2.0 * math.pi * target / n_targets
    # A positive rotation about (sin φ, 0, −cos φ) moves the rim point in direction
    # (cos φ, 0, sin φ) downwards: (axis × d)_y = −1.
    axis = (math.sin(phi), 0.0, -math.cos(phi))
    angle = Profile.of((0.0, 0.0), (start, 0.0), (start + t_tilt, math.radians(tilt_deg)))
    return PivotMotion((0.0, 0.0, 0.0), axis, angle, Profile.of((0.0, centre)))


def ladle_scoop(bowl_centre_local, basin_surface, target_above, *, start: float = 0.3,
                dip: float = 0.04) -> PivotMotion:
    """Scoop with a ladle and pour: lower the bowl of the ladle (object-frame point
    ``bowl_centre_local``) into the basin (world point ``basin_surface`` (3,) on the liquid
    surface), drag it along, lift out, carry over ``target_above`` (3,) and tip it about +z.
    """
    s = np.asarray(basin_surface, float)
    up = np.array([0.0, 0.12, 0.0])
    down = s + np.array([-0.03, -dip, 0.0])
    along = s + np.array([0.03, -dip, 0.0])
    over = np.asarray(target_above, float)
    t = np.cumsum([start, 1.0, 0.8, 0.8, 1.2, 0.4, 1.2, 1.5])
    path = Profile.of((0.0, s + up), (t[0], s + up), (t[1], down), (t[2], along), (t[3], s + up),
                      (t[4], over), (t[5], over), (t[7], over))
    tilt = math.radians(120.0)
    angle = Profile.of((0.0, 0.0), (t[5], 0.0), (t[6], tilt), (t[7], tilt))
    return PivotMotion(tuple(bowl_centre_local), (0.0, 0.0, 1.0), angle, path)


def slide(start_world, end_world, *, start: float, duration: float) -> PivotMotion:
    """Translate without rotating from ``start_world`` to ``end_world`` (3,) m (e.g. the
    catching cup sliding in x under a stream)."""
    path = Profile.of((0.0, start_world), (start, start_world), (start + duration, end_world))
    return PivotMotion((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), Profile.of((0.0, 0.0)), path)


def sample(motions, times) -> np.ndarray:
    """Poses of every motion at every time: (T, M, 7) float64 for ``times`` (T,) s."""
    return np.stack([np.stack([m(float(t)) for m in motions]) for t in np.asarray(times, float)])
