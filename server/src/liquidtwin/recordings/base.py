"""Values shared by the recording writer and reader: :class:`CameraInfo`, :class:`RecordingError`
and the checks on names and 7-D poses.

A pose is a (7,) float64 array (tx, ty, tz, qx, qy, qz, qw): translation in m, then a unit
quaternion; it maps the child frame (object or camera) to the world.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

#: |‖q‖ − 1| the writer accepts in a pose quaternion (quaternions are stored as given).
WRITE_QUAT_TOL = 1e-6
#: |‖q‖ − 1| the reader and :class:`CameraInfo` accept (trackers round their output).
READ_QUAT_TOL = 1e-3

_CAMERA_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")


class RecordingError(ValueError):
    """A recording cannot be read (or written) as liquidtwin measured data.

    The message names the file, the topic and the problem.
    """


def check_camera_name(name) -> str:
    """A camera name goes into topic names (``/camera/<name>/mask``): letters, digits, ``_.-``."""
    if not isinstance(name, str) or not _CAMERA_NAME.match(name):
        raise ValueError(f"camera name {name!r} must be a non-empty string of letters, digits, "
                         "'_', '.' or '-' (it becomes part of the topic names)")
    return name


def check_object_name(name) -> str:
    """An object (or camera) name is the child frame id of its transform: a non-empty string."""
    if not isinstance(name, str) or not name or name != name.strip():
        raise ValueError(f"frame name {name!r} must be a non-empty string without "
                         "leading or trailing spaces")
    return name


def fmt_time(ns: int) -> str:
    """Nanoseconds as exact seconds, e.g. "1700000000.016666667 s" (a float would round)."""
    sign = "-" if ns < 0 else ""
    return f"{sign}{abs(ns) // 10**9}.{abs(ns) % 10**9:09d} s"


def as_numpy(a) -> np.ndarray:
    """A numpy view of an array-like or a (detached, CPU) torch tensor."""
    if hasattr(a, "detach"):
        a = a.detach().cpu().numpy()
    return np.asarray(a)


def check_poses(poses, what: str, tol: float = WRITE_QUAT_TOL) -> np.ndarray:
    """Validate (..., 7) poses: finite, unit quaternions within ``tol``; returns float64 (..., 7).

    Raises ValueError naming ``what`` (e.g. "pose of 'cup'") and the offending row.
    """
    p = as_numpy(poses)
    if not (np.issubdtype(p.dtype, np.floating) or np.issubdtype(p.dtype, np.integer)):
        raise ValueError(f"{what}: poses must be a numeric array, got dtype {p.dtype}")
    p = p.astype(np.float64)
    if p.ndim < 1 or p.shape[-1] != 7:
        raise ValueError(f"{what}: poses must have shape (..., 7) = (tx, ty, tz, qx, qy, qz, qw), "
                         f"got {p.shape}")
    flat = p.reshape(-1, 7)
    bad = ~np.isfinite(flat).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{what}: pose {i} is not finite (NaN or inf): {flat[i].tolist()}")
    norm = np.linalg.norm(flat[:, 3:], axis=1)
    off = np.abs(norm - 1.0) > tol
    if off.any():
        i = int(np.flatnonzero(off)[0])
        raise ValueError(f"{what}: pose {i} has quaternion norm {norm[i]:.9g}, expected a unit "
                         f"quaternion (qx, qy, qz, qw) within {tol:g}")
    return p


def _frozen(a, shape: tuple[int, ...], what: str) -> np.ndarray:
    a = as_numpy(a)
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise ValueError(f"{what} must be numeric, got dtype {a.dtype}")
    a = np.array(a, dtype=np.float64)
    if a.shape != shape:
        raise ValueError(f"{what} must have shape {shape}, got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{what} must be finite, got {a.tolist()}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class CameraInfo:
    """A calibrated pinhole camera at one pose, as a recording stores it.

    Fields:
      name: camera name = frame id of its calibration, images and transform (the writer
        also needs it topic-safe: letters, digits, '_', '.', '-').
      width, height: image size, px.
      K: (3, 3) intrinsics [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], px.
      D: (5,) plumb-bob distortion (k1, k2, p1, p2, k3), unitless.
      pose: (7,) camera → world (tx, ty, tz m, qx, qy, qz, qw); the camera frame is OpenCV's
        (x right, y down, z forward).

    Arrays are stored as read-only float64 copies; ``==`` compares them exactly.
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    D: np.ndarray
    pose: np.ndarray

    def __post_init__(self):
        check_object_name(self.name)
        for field in ("width", "height"):
            v = getattr(self, field)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise ValueError(f"camera {self.name!r}: {field} must be a positive integer "
                                 f"(pixels), got {v!r}")
            object.__setattr__(self, field, int(v))
        K = _frozen(self.K, (3, 3), f"camera {self.name!r}: K")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]) \
                or K[1, 0] != 0 or K[0, 1] != 0:
            raise ValueError(f"camera {self.name!r}: K must be [[fx, 0, cx], [0, fy, cy], "
                             f"[0, 0, 1]] with fx, fy > 0, got {K.tolist()}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", _frozen(self.D, (5,), f"camera {self.name!r}: D"))
        pose = check_poses(self.pose, f"camera {self.name!r}", READ_QUAT_TOL)
        if pose.shape != (7,):
            raise ValueError(f"camera {self.name!r}: pose must have shape (7,), got {pose.shape}")
        pose = pose.copy()
        pose.setflags(write=False)
        object.__setattr__(self, "pose", pose)

    def same_intrinsics(self, other: "CameraInfo") -> bool:
        """True when size, K and D are exactly equal (the pose may differ)."""
        return (self.width, self.height) == (other.width, other.height) \
            and np.array_equal(self.K, other.K) and np.array_equal(self.D, other.D)

    def with_pose(self, pose) -> "CameraInfo":
        """The same camera at another (7,) pose."""
        return CameraInfo(self.name, self.width, self.height, self.K, self.D, pose)

    def __eq__(self, other) -> bool:
        if not isinstance(other, CameraInfo):
            return NotImplemented
        return self.name == other.name and self.same_intrinsics(other) \
            and np.array_equal(self.pose, other.pose)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return (f"CameraInfo(name={self.name!r}, width={self.width}, height={self.height}, "
                f"K={self.K.tolist()}, D={self.D.tolist()}, pose={self.pose.tolist()})")
