"""Causal filtering of streamed object poses (SessionSpec.pose_filter).

An object tracker's poses carry white jitter (0.2–2 mm, 0.1–0.6° per sample is typical). The
session moves the model's walls along the poses it is given, and differences them into wall
velocities, so jitter of σ at 30–60 Hz becomes wall speeds of √2·σ·rate — 0.04 m/s and 0.6
rad/s for 0.5 mm and 0.3° at 60 Hz (bench/discrepancy_drag_bias.py --pose-error): the
model's container shakes its liquid. The discrepancy analysis smooths recorded poses offline
(zero-phase, ``recordings._interp.smooth_poses``); a live session can only use the past.

:class:`PoseFilter` is a constant-velocity Kalman filter per object: translation and rotation
each have a 2-state (value, rate) model per axis driven by white acceleration (discrete
piecewise-constant acceleration of std ``acceleration``), measured with white noise of std
``noise``. The three axes share one 2×2 covariance (isotropic noise, the same sample times).
The rotation is filtered on the manifold: predict q ← exp(ω dt) ⊗ q, innovation r = log(z ⊗
q⁻¹) (world-frame rotation vector, shortest arc), update q ← exp(k₀ r) ⊗ q, ω ← ω + k₁ r. A
constant-velocity motion is followed without lag once the rate has converged; the price is
overshoot where the motion turns sharply, bounded by ``acceleration``. Irregular frame times
are handled exactly (the covariance is propagated over each frame's own dt).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..sensors.poses import _quat_exp, _quat_mul
from .errors import BAD_REQUEST, EngineError

#: Process noise when a spec gives the measurement noise only: white acceleration of this std,
#: m/s² and rad/s². Chosen on the 18 quick tracking pours' poses against their truth: of
#: 1, 2, 5, 10 m/s² and 5, 10, 20, 40 rad/s² the smallest position error (2) and rotation
#: error (10), which cut the speed errors the walls see by 33 % and 46 %
#: (``bench/tracking_pose_noise.py --no-replay --filter …``, README); lower values smooth the
#: speeds more but lag where a pour starts and turns, and the pose errors grow.
DEFAULT_ACCELERATION_M_S2 = 2.0
DEFAULT_ANGULAR_ACCELERATION_RAD_S2 = 10.0
#: Initial rate uncertainty (std) at an object's first pose: m/s, rad/s.
INITIAL_RATE_STD = (1.0, 3.0)


def quat_log(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (x, y, z, w) → (..., 3) rotation vectors, rad, shortest arc."""
    q = np.where(q[..., 3:4] < 0, -q, q)
    s = np.linalg.norm(q[..., :3], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., 3:4])
    k = np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 2.0 / np.maximum(q[..., 3:4], 1e-300))
    return q[..., :3] * k


def quat_inverse(q: np.ndarray) -> np.ndarray:
    return np.concatenate([-q[..., :3], q[..., 3:]], axis=-1)


@dataclass(frozen=True)
class PoseFilterSettings:
    """Measurement noise (std per axis, per sample) and process noise (white acceleration std)."""

    position_noise_m: float
    rotation_noise_rad: float
    acceleration_m_s2: float = DEFAULT_ACCELERATION_M_S2
    angular_acceleration_rad_s2: float = DEFAULT_ANGULAR_ACCELERATION_RAD_S2

    @staticmethod
    def from_spec(msg) -> "PoseFilterSettings | None":
        """From a ``pb.PoseFilter``; None when it asks for no filtering (both noises 0).
        EngineError(BAD_REQUEST) for a negative or non-finite number."""
        vals = {f: float(getattr(msg, f)) for f in ("position_noise_m", "rotation_noise_rad", "acceleration_m_s2",
                                                    "angular_acceleration_rad_s2")}
        for f, v in vals.items():
            if not (math.isfinite(v) and v >= 0):
                raise EngineError(BAD_REQUEST, f"pose_filter.{f} must be a finite number >= 0, got {v}")
        if vals["position_noise_m"] == 0 and vals["rotation_noise_rad"] == 0:
            return None
        return PoseFilterSettings(vals["position_noise_m"], vals["rotation_noise_rad"],
                                  vals["acceleration_m_s2"] or DEFAULT_ACCELERATION_M_S2,
                                  vals["angular_acceleration_rad_s2"] or DEFAULT_ANGULAR_ACCELERATION_RAD_S2)


def kalman_gain(P: np.ndarray, dt: float, accel: float, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """One predict + update of the (value, rate) covariance ``P`` (2, 2) over ``dt``; returns
    (the gain (2,) applied to the innovation, the updated covariance). ``noise`` 0: the
    measurement is taken as exact."""
    F = np.array([[1.0, dt], [0.0, 1.0]])
    G = np.array([0.5 * dt * dt, dt])
    P = F @ P @ F.T + accel * accel * np.outer(G, G)
    s = P[0, 0] + noise * noise
    k = P[:, 0] / s if s > 0 else np.array([1.0, 0.0])
    P = P - np.outer(k, P[0, :])
    return k, 0.5 * (P + P.T)


class PoseFilter:
    """Per-object constant-velocity Kalman filter of (7,) poses (tx ty tz qx qy qz qw); see the
    module doc. :meth:`update` takes the objects measured at a frame and returns their filtered
    poses; objects not measured keep their state."""

    def __init__(self, settings: PoseFilterSettings, n_objects: int):
        self.settings, self.n = settings, int(n_objects)
        self.reset()

    def reset(self) -> None:
        n = self.n
        self.t = np.full(n, np.nan)                   # time of each object's last update, s (nan: none yet)
        self.pose = np.zeros((n, 7))
        self.pose[:, 6] = 1.0
        self.rate = np.zeros((n, 6))                  # linear m/s, angular rad/s (world frame)
        self.P = np.zeros((n, 2, 2, 2))               # [object, translation/rotation, 2, 2]

    def update(self, t_s: float, index: int, z: np.ndarray) -> np.ndarray:
        """Fuse object ``index``'s measured pose ``z`` (7,) at time ``t_s`` (s, not before its
        previous one); returns the filtered pose (7,), quaternion unit and in z's hemisphere."""
        s, j = self.settings, int(index)
        z = np.asarray(z, np.float64)
        if not np.isfinite(self.t[j]):
            self.t[j], self.pose[j], self.rate[j] = t_s, z, 0.0
            for a, (noise, rate_std) in enumerate(zip((s.position_noise_m, s.rotation_noise_rad), INITIAL_RATE_STD)):
                self.P[j, a] = np.diag([noise * noise, rate_std * rate_std])
            return z.copy()
        dt = max(float(t_s) - float(self.t[j]), 0.0)
        self.t[j] = t_s
        # translation
        k, self.P[j, 0] = kalman_gain(self.P[j, 0], dt, s.acceleration_m_s2, s.position_noise_m)
        pred = self.pose[j, :3] + self.rate[j, :3] * dt
        r = z[:3] - pred
        self.pose[j, :3] = pred + k[0] * r
        self.rate[j, :3] += k[1] * r
        # rotation, on the manifold
        k, self.P[j, 1] = kalman_gain(self.P[j, 1], dt, s.angular_acceleration_rad_s2, s.rotation_noise_rad)
        q_pred = _quat_mul(_quat_exp(self.rate[j, 3:] * dt), self.pose[j, 3:])
        r = quat_log(_quat_mul(z[3:], quat_inverse(q_pred)))
        q = _quat_mul(_quat_exp(k[0] * r), q_pred)
        q = q / np.linalg.norm(q)
        self.pose[j, 3:] = -q if float(q @ z[3:]) < 0 else q
        self.rate[j, 3:] += k[1] * r
        return self.pose[j].copy()

    def state_dict(self) -> dict:
        return {"t": torch.as_tensor(self.t.copy()), "pose": torch.as_tensor(self.pose.copy()),
                "rate": torch.as_tensor(self.rate.copy()), "P": torch.as_tensor(self.P.copy())}

    def load_state_dict(self, state: dict) -> None:
        if not state:
            self.reset()
            return
        shapes = {"t": (self.n,), "pose": (self.n, 7), "rate": (self.n, 6), "P": (self.n, 2, 2, 2)}
        for key, shape in shapes.items():
            if key not in state or tuple(state[key].shape) != shape:
                raise EngineError(BAD_REQUEST, f"checkpoint's pose filter: {key!r} missing or not of shape {shape}")
        self.t, self.pose = state["t"].numpy().astype(np.float64), state["pose"].numpy().astype(np.float64)
        self.rate, self.P = state["rate"].numpy().astype(np.float64), state["P"].numpy().astype(np.float64)
