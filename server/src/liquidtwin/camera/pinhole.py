"""Pinhole camera with plumb-bob distortion, matching OpenCV's ``projectPoints`` (SPEC §2).

Frames and conventions:
- ``pose`` (7,) = (tx, ty, tz, qx, qy, qz, qw) maps the **camera frame to the world** (the
  camera centre is ``pose[:3]`` in m). The camera frame is OpenCV's optical frame: x right,
  y down, z forward (along the optical axis).
- Pixel coordinates (u, v) are OpenCV's: u to the right, v down, the *centre* of pixel
  (row i, column j) is at (u, v) = (j, i). The image covers u ∈ [−0.5, W − 0.5].
- Distortion is plumb bob (k1, k2, p1, p2, k3), as in ROS ``CameraInfo`` and Foxglove
  ``CameraCalibration``.

Projection is plain torch, so it is differentiable with respect to points and pose.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import torch

from ..sim.sdf import quat_to_matrix
from ..sim.segments import world_points as _check_points


def _floats(values) -> list:
    """An array-like (list, protobuf field, numpy array — possibly a read-only view of a
    message buffer — or tensor) copied to Python lists, so no read-only buffer is wrapped."""
    return values.tolist() if hasattr(values, "tolist") else list(values)


DISTORTION_MODEL = "plumb_bob"
_QUAT_NORM_TOL = 1e-2  # |‖q‖ − 1| allowed in a camera pose (then normalised on use)


def matrix_to_quat(R: torch.Tensor) -> torch.Tensor:
    """Rotation matrix (3, 3) → unit quaternion (4,) (x, y, z, w), w ≥ 0 (Shepperd's method)."""
    R = torch.as_tensor(R, dtype=torch.float64)
    tr = float(R[0, 0] + R[1, 1] + R[2, 2])
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + float(R[0, 0] - R[1, 1] - R[2, 2]))
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + float(R[1, 1] - R[0, 0] - R[2, 2]))
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + float(R[2, 2] - R[0, 0] - R[1, 1]))
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    q = torch.stack([torch.as_tensor(c, dtype=torch.float64) for c in q])
    q = q / q.norm()
    return -q if q[3] < 0 else q


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated pinhole camera placed in the world.

    Attributes:
      width, height: image size, px (> 0).
      fx, fy: focal lengths, px (> 0).
      cx, cy: principal point, px (OpenCV pixel-centre convention, see module doc).
      pose: (7,) camera → world (tx, ty, tz m, qx, qy, qz, qw), OpenCV optical frame. May
        require grad (camera-offset estimation); it is used as given, the quaternion
        normalised on use. Stored as given (non-tensors as float64); cast to the points'
        dtype and device when projecting.
      distortion: (5,) plumb bob (k1, k2, p1, p2, k3), dimensionless; zeros = ideal pinhole.
      name: frame id / label.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    pose: torch.Tensor
    distortion: torch.Tensor = field(default_factory=lambda: torch.zeros(5, dtype=torch.float64))
    name: str = "camera"

    def __post_init__(self):
        n = self.name
        for k in ("width", "height"):
            v = getattr(self, k)
            whole = isinstance(v, numbers.Integral) or (isinstance(v, float) and v.is_integer())
            if isinstance(v, bool) or not whole:
                raise ValueError(f"camera {n!r}: {k} must be a whole number of pixels, got {v!r}")
            if int(v) <= 0:
                raise ValueError(f"camera {n!r}: {k} must be > 0 px, got {v}")
            object.__setattr__(self, k, int(v))
        for k in ("fx", "fy", "cx", "cy"):
            v = float(getattr(self, k))
            if not math.isfinite(v):
                raise ValueError(f"camera {n!r}: {k} must be finite, got {v}")
            object.__setattr__(self, k, v)
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"camera {n!r}: focal lengths must be > 0 px, "
                             f"got fx={self.fx}, fy={self.fy}")
        pose = self.pose
        if not isinstance(pose, torch.Tensor):
            pose = torch.tensor(_floats(pose), dtype=torch.float64)
        if not pose.is_floating_point():
            pose = pose.to(torch.float64)
        if pose.shape != (7,):
            raise ValueError(f"camera {n!r}: pose must be (7,) (tx ty tz qx qy qz qw), "
                             f"got {tuple(pose.shape)}")
        if not bool(torch.isfinite(pose).all()):
            raise ValueError(f"camera {n!r}: pose contains NaN or inf")
        qn = float(pose[3:].detach().norm())
        if abs(qn - 1.0) > _QUAT_NORM_TOL:
            raise ValueError(f"camera {n!r}: pose quaternion (x y z w) must be unit length, "
                             f"its norm is {qn:.4g}")
        object.__setattr__(self, "pose", pose)
        d = torch.as_tensor(self.distortion, dtype=torch.float64) if not isinstance(
            self.distortion, torch.Tensor) else self.distortion
        if d.numel() == 4:  # k1 k2 p1 p2 without k3 (OpenCV accepts this too)
            d = torch.cat([d.reshape(4), d.new_zeros(1)])
        if d.shape != (5,):
            raise ValueError(f"camera {n!r}: distortion must be (5,) plumb bob (k1 k2 p1 p2 k3), "
                             f"got shape {tuple(d.shape)}")
        if not bool(torch.isfinite(d).all()):
            raise ValueError(f"camera {n!r}: distortion contains NaN or inf")
        object.__setattr__(self, "distortion", d)

    # ------------------------------------------------------------------ constructors

    @classmethod
    def look_at(cls, eye, target, up=(0.0, 1.0, 0.0), width: int = 640, height: int = 480,
                fov_y_deg: float | None = None, fx: float | None = None, fy: float | None = None,
                cx: float | None = None, cy: float | None = None, distortion=None,
                name: str = "camera") -> "Camera":
        """A camera at ``eye`` (3,) m looking at ``target`` (3,) m, image "up" towards ``up`` (3,).

        Give either ``fov_y_deg`` (vertical field of view, degrees, in (0, 180); square
        pixels, fx = fy) or ``fx`` (px; ``fy`` defaults to ``fx``). The principal point defaults to the image centre
        ((W − 1)/2, (H − 1)/2) in the pixel-centre convention.
        """
        eye = torch.as_tensor(eye, dtype=torch.float64).reshape(-1)
        target = torch.as_tensor(target, dtype=torch.float64).reshape(-1)
        up = torch.as_tensor(up, dtype=torch.float64).reshape(-1)
        if eye.shape != (3,) or target.shape != (3,) or up.shape != (3,):
            raise ValueError("look_at: eye, target and up must each be 3 numbers")
        if not bool(torch.isfinite(torch.cat([eye, target, up])).all()):
            raise ValueError("look_at: eye, target or up contains NaN or inf")
        fwd = target - eye
        if float(fwd.norm()) < 1e-9:
            raise ValueError("look_at: eye and target coincide; the viewing direction is undefined")
        fwd = fwd / fwd.norm()
        right = torch.linalg.cross(fwd, up)
        if float(right.norm()) < 1e-6 * max(float(up.norm()), 1e-300):
            raise ValueError("look_at: 'up' is parallel to the viewing direction; "
                             "pass another up vector")
        right = right / right.norm()
        down = torch.linalg.cross(fwd, right)
        R = torch.stack([right, down, fwd], 1)  # columns: camera axes in the world
        if (fov_y_deg is None) == (fx is None) or (fov_y_deg is not None and fy is not None):
            raise ValueError("look_at: give exactly one of fov_y_deg or fx (and fy only with fx)")
        if fov_y_deg is not None:
            if not 0.0 < float(fov_y_deg) < 180.0:
                raise ValueError(f"look_at: fov_y_deg must be in (0, 180) degrees, got {fov_y_deg}")
            fx = fy = 0.5 * height / math.tan(math.radians(float(fov_y_deg)) / 2)
        else:
            fy = fx if fy is None else fy
        pose = torch.cat([eye, matrix_to_quat(R)])  # float64; cast to the points' dtype on use
        return cls(width, height, fx, fy, (width - 1) / 2 if cx is None else cx,
                   (height - 1) / 2 if cy is None else cy, pose,
                   torch.zeros(5, dtype=torch.float64) if distortion is None else distortion, name)

    @classmethod
    def from_calibration(cls, K, D, width: int, height: int, pose,
                         name: str = "camera") -> "Camera":
        """From ROS/Foxglove calibration fields: K (9,) or (3, 3) row-major intrinsics (zero
        skew), D plumb bob (5,) (or (4,) or empty), image size px, pose (7,) camera → world."""
        K = torch.tensor(_floats(K), dtype=torch.float64).reshape(-1)
        if K.numel() != 9:
            raise ValueError(f"from_calibration: K must have 9 entries (3x3 row-major), "
                             f"got {K.numel()}")
        if not bool(torch.isfinite(K).all()):
            raise ValueError("from_calibration: K contains NaN or inf")
        if abs(float(K[1])) > 1e-9 or K[[3, 6, 7]].abs().max() > 0 or float(K[8]) != 1:
            raise ValueError(f"from_calibration: K must be [fx 0 cx; 0 fy cy; 0 0 1] (no skew), "
                             f"got {K.tolist()}")
        D = torch.tensor(_floats(D), dtype=torch.float64).reshape(-1)
        if D.numel() == 0:
            D = torch.zeros(5, dtype=torch.float64)
        return cls(width, height, float(K[0]), float(K[4]), float(K[2]), float(K[5]), pose, D, name)

    # ------------------------------------------------------------------ matrices and fields

    @property
    def K(self) -> torch.Tensor:
        """(3, 3) intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], float64."""
        return torch.tensor([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]],
                            dtype=torch.float64)

    @property
    def position(self) -> torch.Tensor:
        """(3,) camera centre in the world, m."""
        return self.pose[:3]

    @property
    def rotation(self) -> torch.Tensor:
        """(3, 3) camera → world rotation; columns: the camera x, y, z axes in the world."""
        return quat_to_matrix(self.pose[3:])

    def with_pose(self, pose) -> "Camera":
        """The same camera at another pose (7,) (e.g. a tensor that requires grad)."""
        return Camera(self.width, self.height, self.fx, self.fy, self.cx, self.cy, pose,
                      self.distortion, self.name)

    def to_foxglove_fields(self) -> dict:
        """Fields of a ``foxglove.CameraCalibration`` / ROS ``CameraInfo`` (row-major lists)."""
        fx, fy, cx, cy = self.fx, self.fy, self.cx, self.cy
        return dict(frame_id=self.name, width=self.width, height=self.height,
                    distortion_model=DISTORTION_MODEL, D=[float(v) for v in self.distortion],
                    K=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
                    R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                    P=[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])

    # ------------------------------------------------------------------ projection

    def world_to_camera(self, x: torch.Tensor) -> torch.Tensor:
        """World points (N, 3) m → camera-frame points (N, 3) m (x right, y down, z forward)."""
        x = _check_points(x)
        pose = self.pose.to(device=x.device, dtype=x.dtype)
        return (x - pose[:3]) @ quat_to_matrix(pose[3:])  # R^T (x − t), row vectors

    def project(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """World points (N, 3) m → (uv (N, 2) px, depth (N,) m), as ``cv2.projectPoints``.

        depth is the camera-frame z. For points with depth ≤ 0 (behind the camera) uv is
        not meaningful (the division uses a tiny positive depth instead of zero); use
        :func:`liquidtwin.camera.visible` to decide what is seen. Differentiable w.r.t.
        x and the pose.
        """
        pc = self.world_to_camera(x)
        z = pc[:, 2]
        eps = torch.finfo(z.dtype).tiny ** 0.5
        zs = torch.where(z.abs() < eps, torch.full_like(z, eps), z)
        a, b = pc[:, 0] / zs, pc[:, 1] / zs
        d = self.distortion.to(device=x.device, dtype=x.dtype)
        if bool((self.distortion != 0).any()):
            k1, k2, p1, p2, k3 = d.unbind()
            r2 = a * a + b * b
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            a, b = (a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a),
                    b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b)
        uv = torch.stack([self.fx * a + self.cx, self.fy * b + self.cy], -1)
        return uv, z
