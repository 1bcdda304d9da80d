"""Pose time series: sample a (K, 7) series at other times (linear translation, slerp rotation)."""

from __future__ import annotations

import numpy as np


def _slerp(q0: np.ndarray, q1: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Shortest-arc slerp between rows of (M, 4) unit quaternions at fractions a (M,)."""
    dot = np.sum(q0 * q1, axis=1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    small = theta < 1e-6
    s = np.where(small, 1.0, np.sin(theta))
    w0 = np.where(small, 1.0 - a, np.sin((1.0 - a) * theta) / s)
    w1 = np.where(small, a, np.sin(a * theta) / s)
    q = w0[:, None] * q0 + w1[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def interpolate_poses(times: np.ndarray, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Poses (M, 7) at times t (M,) ns from a series (K,) ns, (K, 7), K ≥ 1, times increasing.

    At a sample time the sample is returned exactly; between samples the translation is
    linear and the rotation is slerped; before the first / after the last sample the end
    pose is held.
    """
    times = np.asarray(times, dtype=np.int64)
    t = np.asarray(t, dtype=np.int64)
    hi = np.clip(np.searchsorted(times, t, side="left"), 0, len(times) - 1)
    exact = times[hi] == t
    out = poses[hi].copy()
    between = ~exact & (t > times[0]) & (t < times[-1])
    if between.any():
        j = hi[between]
        t0, t1 = times[j - 1], times[j]
        a = ((t[between] - t0) / (t1 - t0)).astype(np.float64)
        p0, p1 = poses[j - 1], poses[j]
        out[between, :3] = p0[:, :3] + a[:, None] * (p1[:, :3] - p0[:, :3])
        out[between, 3:] = _slerp(p0[:, 3:], p1[:, 3:], a)
    out[t <= times[0]] = poses[0]
    out[t >= times[-1]] = poses[-1]
    out[exact] = poses[hi[exact]]
    return out
