"""Object tracker noise: white jitter plus a slowly drifting bias on every 6-D pose.

A pose is (tx, ty, tz, qx, qy, qz, qw): translation in m, unit quaternion x-y-z-w, object
frame → world. Errors are applied in the world frame:

    t' = t + b_t + e_t                     (m)
    q' = exp(b_r + e_r) ⊗ q                (rotation vectors b_r, e_r in rad)

with e white Gaussian (std ``pos_sigma_m`` / ``rot_sigma_rad`` per axis) and b a
first-order Gauss–Markov (AR(1)) drift of stationary std ``drift_m`` / ``drift_rad`` per axis
and correlation time ``drift_frames``, plus an optional constant bias.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ._common import SensorInputError, check_generator, check_number


@dataclass(frozen=True)
class PoseNoise:
    """Parameters of :func:`noisy_poses` (all std values are per axis).

    pos_sigma_m:   white position noise, m, [0, 0.1]
    rot_sigma_rad: white rotation noise (rotation-vector components), rad, [0, 0.5]
    drift_m:       stationary std of the slow position drift, m, [0, 0.1]
    drift_rad:     stationary std of the slow rotation drift, rad, [0, 0.5]
    drift_frames:  correlation time of the drift, frames, [1, 1e6]
    """

    pos_sigma_m: float = 0.5e-3
    rot_sigma_rad: float = math.radians(0.3)
    drift_m: float = 0.5e-3
    drift_rad: float = math.radians(0.2)
    drift_frames: float = 100.0

    NONE: ClassVar["PoseNoise"]

    def __post_init__(self):
        for name, lo, hi in (("pos_sigma_m", 0, 0.1), ("rot_sigma_rad", 0, 0.5),
                             ("drift_m", 0, 0.1), ("drift_rad", 0, 0.5), ("drift_frames", 1, 1e6)):
            value = check_number(f"PoseNoise.{name}", getattr(self, name), lo, hi)
            object.__setattr__(self, name, value)

    @staticmethod
    def sample(rng: np.random.Generator) -> "PoseNoise":
        """Random plausible tracker quality: white 0.2–2 mm / 0.1–0.6°, drift 0–2 mm / 0–0.5°
        with a correlation time of 30–300 frames."""
        u = check_generator(rng).uniform
        return PoseNoise(pos_sigma_m=u(0.2e-3, 2e-3), rot_sigma_rad=math.radians(u(0.1, 0.6)),
                         drift_m=u(0.0, 2e-3), drift_rad=math.radians(u(0.0, 0.5)),
                         drift_frames=u(30.0, 300.0))


PoseNoise.NONE = PoseNoise(pos_sigma_m=0.0, rot_sigma_rad=0.0, drift_m=0.0, drift_rad=0.0)


def noisy_poses(poses: np.ndarray, rng: np.random.Generator, noise: PoseNoise | None = None, *,
                pos_sigma_m: float | None = None, rot_sigma_rad: float | None = None,
                drift_m: float | None = None, drift_rad: float | None = None,
                drift_frames: float | None = None, pos_bias_m=None,
                rot_bias_rad=None) -> np.ndarray:
    """Poses as a tracker reports them.

    poses:        (T, n, 7) or (T, 7) true poses per time step (tx ty tz m, qx qy qz qw).
    rng:          numpy Generator (same seed → same output).
    noise:        parameters (default ``PoseNoise()``); keywords override single fields.
    pos_bias_m:   optional constant position offset, (3,) or (n, 3) m, world frame.
    rot_bias_rad: optional constant rotation offset as a rotation vector, (3,) or (n, 3) rad.
    Returns an array of the input's shape (float64, or float32 for float32 input) with unit
    quaternions, each in the same hemisphere as its input quaternion (positive dot product):
    the noise never flips a sign, so a sign-continuous input stays sign-continuous.
    """
    rng = check_generator(rng)
    if noise is None:
        noise = PoseNoise()
    if not isinstance(noise, PoseNoise):
        raise SensorInputError(f"noise must be a PoseNoise, got {type(noise).__name__}")
    overrides = {k: v for k, v in dict(pos_sigma_m=pos_sigma_m, rot_sigma_rad=rot_sigma_rad,
                                       drift_m=drift_m, drift_rad=drift_rad,
                                       drift_frames=drift_frames).items() if v is not None}
    nz = dataclasses.replace(noise, **overrides)
    p = _check_poses(poses)
    squeeze = p.ndim == 2
    if squeeze:
        p = p[:, None, :]
    t_len, n = p.shape[:2]
    x = p.astype(np.float64)
    q = x[..., 3:] / np.linalg.norm(x[..., 3:], axis=-1, keepdims=True)
    bias = np.concatenate([np.broadcast_to(_bias("pos_bias_m", pos_bias_m, n), (n, 3)),
                           np.broadcast_to(_bias("rot_bias_rad", rot_bias_rad, n), (n, 3))], -1)
    sig = np.array([nz.pos_sigma_m] * 3 + [nz.rot_sigma_rad] * 3)
    err = rng.standard_normal((t_len, n, 6)) * sig
    err += _drift(rng, t_len, n, np.array([nz.drift_m] * 3 + [nz.drift_rad] * 3), nz.drift_frames)
    err += bias
    out = np.empty_like(x)
    out[..., :3] = x[..., :3] + err[..., :3]
    out[..., 3:] = _same_hemisphere(_quat_mul(_quat_exp(err[..., 3:]), q), q)
    out = out.astype(p.dtype if p.dtype == np.float32 else np.float64)
    return out[:, 0, :] if squeeze else out


def _check_poses(poses) -> np.ndarray:
    p = np.asarray(poses)
    if p.dtype.kind not in "fiu" or p.dtype == np.bool_:
        raise SensorInputError(f"poses must be a float array, got dtype {p.dtype}")
    if p.ndim not in (2, 3) or p.shape[-1] != 7 or p.shape[0] < 1:
        raise SensorInputError(f"poses must be (T, n, 7) or (T, 7) (tx ty tz qx qy qz qw), "
                               f"got shape {p.shape}")
    if not np.isfinite(p).all():
        raise SensorInputError("poses contain NaN or inf")
    if (np.linalg.norm(p[..., 3:].astype(np.float64), axis=-1) < 1e-8).any():
        raise SensorInputError("a pose quaternion has zero norm")
    return p


def _bias(name: str, value, n: int) -> np.ndarray:
    if value is None:
        return np.zeros(3)
    b = np.asarray(value, dtype=np.float64)
    if b.shape not in ((3,), (n, 3)) or not np.isfinite(b).all():
        raise SensorInputError(f"{name} must be finite, (3,) or ({n}, 3), got shape {b.shape}")
    return b


def _drift(rng: np.random.Generator, t_len: int, n: int, std: np.ndarray, tau: float) -> np.ndarray:
    """(T, n, 6) AR(1) process with stationary std ``std`` (6,) and correlation time ``tau``."""
    a = math.exp(-1.0 / tau)
    shocks = rng.standard_normal((t_len, n, 6)) * std
    shocks[1:] *= math.sqrt(1.0 - a * a)
    for t in range(1, t_len):
        shocks[t] += a * shocks[t - 1]
    return shocks


def _quat_exp(w: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors (rad) → (..., 4) unit quaternions (x, y, z, w)."""
    angle = np.linalg.norm(w, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(half)/angle, with its limit 1/2 for tiny angles
    k = np.where(angle > 1e-12, np.sin(half) / np.maximum(angle, 1e-300),
                 0.5 - angle * angle / 48.0)
    return np.concatenate([w * k, np.cos(half)], axis=-1)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of (..., 4) quaternions (x, y, z, w)."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def _same_hemisphere(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions normalised and sign-flipped where their dot product with ``ref`` < 0."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where((q * ref).sum(-1, keepdims=True) < 0, -q, q)
