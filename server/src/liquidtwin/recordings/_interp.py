"""Pose time series: sample a (K, 7) series at other times (linear translation, slerp rotation)."""

from __future__ import annotations

import numpy as np

#: σ (s) of the zero-phase smoothing the discrepancy analysis applies to recorded poses
#: (:func:`smooth_poses`): 3 samples of a 60 Hz tracker, well below the time scale of a pour's
#: motions.
POSE_SMOOTHING_S = 0.05


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


def smooth_poses(t: np.ndarray, poses: np.ndarray, sigma_s: float, clip: float = 3.0) -> np.ndarray:
    """Zero-phase smoothing of a pose series: at every sample, a local linear fit with Gaussian
    weights (std ``sigma_s`` seconds, cut at 4 σ) through the neighbouring samples, the change
    to each component at most ``clip`` × that component's white-noise level.

    ``t`` (K,) s increasing, ``poses`` (K, 7) or (K, n, 7). Translations are fitted per
    component; quaternions are first made sign-continuous along time, fitted per component
    and renormalised (the chordal mean, close to the rotation mean for the small angles a
    window spans), returned in the input's hemisphere. A motion linear in time is kept
    exactly, so no lag and no bias on constant-velocity segments; what goes is the white
    jitter of a tracker, whose differences a simulator would read as the container shaking.
    Where the motion bends sharply (a fast dump starting), the local line would cut the corner
    by more than the noise; the clip keeps such samples within ``clip`` noise levels of the
    measurement. The noise level per object and component is estimated from the series itself:
    1.4826 × the median absolute second difference / √6 (white noise of std σ has second
    differences of std √6 σ; the median ignores the few large ones a motion's corners give).
    A sample with no neighbour within 4 σ is kept as it is; ``sigma_s`` ≤ 0 returns a copy.
    """
    t = np.asarray(t, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)
    squeeze = p.ndim == 2
    if not sigma_s > 0 or len(t) < 2:
        return p.copy()
    y = _continuous(p[:, None, :] if squeeze else p)
    reach = 4.0 * sigma_s
    lo = np.searchsorted(t, t - reach, side="left")
    hi = np.searchsorted(t, t + reach, side="right")
    idx = np.arange(len(t))
    m = int(max((idx - lo).max(), (hi - 1 - idx).max()))
    s0 = np.zeros(len(t))
    s1, s2 = np.zeros(len(t)), np.zeros(len(t))
    sy, sty = np.zeros_like(y), np.zeros_like(y)
    for k in range(-m, m + 1):
        j = idx + k
        ok = (j >= 0) & (j < len(t))
        jj = np.clip(j, 0, len(t) - 1)
        d = t[jj] - t
        w = np.where(ok & (np.abs(d) <= reach), np.exp(-0.5 * (d / sigma_s) ** 2), 0.0)
        s0 += w
        s1 += w * d
        s2 += w * d * d
        sy += w[:, None, None] * y[jj]
        sty += (w * d)[:, None, None] * y[jj]
    det = s0 * s2 - s1 * s1
    fit = det > 1e-12 * np.maximum(s0 * s2, 1e-300)
    a = (s2[:, None, None] * sy - s1[:, None, None] * sty) / np.where(fit, det, 1.0)[:, None, None]
    out = np.where(fit[:, None, None], a, y)
    if len(t) >= 3 and clip is not None:
        noise = _white_level(y)
        out = y + np.clip(out - y, -clip * noise, clip * noise)
    qo = out[..., 3:] / np.linalg.norm(out[..., 3:], axis=-1, keepdims=True)
    ref = p[..., 3:] if not squeeze else p[:, None, 3:]
    out[..., 3:] = np.where(np.sum(qo * ref, axis=-1, keepdims=True) < 0, -qo, qo)
    return out[:, 0] if squeeze else out


def _continuous(p: np.ndarray) -> np.ndarray:
    """A (K, n, 7) copy with unit quaternions made sign-continuous along time."""
    y = np.array(p, dtype=np.float64)
    q = y[..., 3:] / np.linalg.norm(y[..., 3:], axis=-1, keepdims=True)
    dots = np.sum(q[1:] * q[:-1], axis=-1)
    sign = np.concatenate([np.ones((1,) + dots.shape[1:]), np.cumprod(np.where(dots < 0, -1.0, 1.0), axis=0)])
    y[..., 3:] = q * sign[..., None]
    return y


def _white_level(y: np.ndarray) -> np.ndarray:
    """(n, 7) white-noise std per object and component of a (K ≥ 3, n, 7) series: 1.4826 ×
    the median absolute second difference / √6 (``smooth_poses``)."""
    d2 = y[2:] - 2.0 * y[1:-1] + y[:-2]
    return 1.4826 * np.median(np.abs(d2), axis=0) / np.sqrt(6.0)


def pose_noise_level(poses: np.ndarray) -> np.ndarray:
    """(n, 2) white tracker-noise level of each object in a raw (K, n, 7) pose series: the
    position std per axis, m, and the rotation std per axis, rad (estimated as in
    ``smooth_poses``). A rotation vector e of per-axis std σ moves a unit quaternion's four
    components by e/2 in total variance 3σ²/4, so σ = √(4/3 · Σ component variances).
    Fewer than 3 samples: zeros (no estimate)."""
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 3 or p.shape[-1] != 7:
        raise ValueError(f"poses must be (K, n, 7), got {p.shape}")
    if len(p) < 3:
        return np.zeros((p.shape[1], 2))
    lv = _white_level(_continuous(p))
    return np.stack([np.sqrt(np.mean(lv[:, :3] ** 2, axis=1)),
                     np.sqrt(4.0 / 3.0 * np.sum(lv[:, 3:] ** 2, axis=1))], 1)
