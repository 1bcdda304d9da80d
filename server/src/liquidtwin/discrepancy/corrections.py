"""The closed-loop tracker's corrections as a measurement of the missing physics.

To stay on the masks the warp-field tracker pushes particles; a push dx applied once per
camera frame (interval τ) is what an unmodelled acceleration a ≈ 2 dx / τ² would have done.
:func:`tracker_corrections` replays an episode through a warp-field session with the base
model and collects, per corrected particle, its velocity and that implied acceleration.
:func:`correction_evidence` reads their structure (drag: opposing the velocity and growing
with speed; wind: uniform; adhesion: only near walls), and :func:`fit_learned` fits the
minimum-norm linear correction a = W [v, 1] (ridge regression, APHYNITY-style: as small as
the data allow) used when no named candidate explains the residual.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..sim import min_sdf

#: Ridge penalty, relative to the mean feature energy.
RIDGE = 0.02


@dataclass(frozen=True)
class Corrections:
    """Per corrected particle and frame: ``t`` (K,) s frame time, ``v`` (K, 3) m/s, ``a``
    (K, 3) m/s² implied by the correction, ``wall_m`` (K,) distance to the nearest object, m."""

    t: np.ndarray
    v: np.ndarray
    a: np.ndarray
    wall_m: np.ndarray
    spacing: float


def tracker_corrections(ep, base) -> Corrections:
    """Replay ``ep`` through a warp-field session whose model is ``base`` (an Extension with
    calibrated ``base`` parameters) and collect its corrections."""
    from ..session import SessionEngine
    spec = pb.SessionSpec()
    spec.CopyFrom(ep.spec)
    spec.tracking = pb.WARP_FIELD
    for k, v in base.base.items():
        setattr(spec.fluid, k, float(v))
    eng = SessionEngine.create(spec)
    cam = ep.camera
    K = [[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]]
    eng.set_camera(cam.name, K=K, D=cam.distortion.tolist(), width=cam.width, height=cam.height,
                   pose=cam.pose.tolist())
    model = eng._scene.model            # the session's own model: objects for wall distances
    frame_of = {int(round(t * 1e6)): j for j, t in enumerate(ep.frame_t)}
    ts, vs, accs, walls = [], [], [], []
    prev_x, prev_t, last_corr_t = None, None, None
    for i, t in enumerate(ep.pose_t):
        eng.advance(float(t), dict(zip(ep.object_names, ep.poses[i])))
        x = eng.positions()
        j = frame_of.get(int(round(float(t) * 1e6)))
        if j is not None:
            eng.correct(cam.name, ep.masks[j])
            after = eng.positions()
            ok = prev_x is not None and prev_x.shape == x.shape == after.shape and last_corr_t is not None
            if ok and t > prev_t:
                tau = float(t - last_corr_t)
                dx = after - x
                moved = np.abs(dx).sum(1) > 0
                if moved.any() and tau > 0:
                    v = (x - prev_x) / float(t - prev_t)
                    ts.append(np.full(int(moved.sum()), float(t)))
                    vs.append(v[moved])
                    accs.append(2.0 * dx[moved] / tau ** 2)
                    poses = torch.as_tensor(ep.poses[i], dtype=torch.float32)
                    walls.append(min_sdf(torch.from_numpy(x[moved]), model.objects, poses).numpy())
            last_corr_t = float(t)
            x = after
        prev_x, prev_t = x, float(t)
    if not vs:
        return Corrections(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), float(model.spacing))
    return Corrections(np.concatenate(ts), np.concatenate(vs), np.concatenate(accs), np.concatenate(walls), float(model.spacing))


def pooled(items: list, keep=None) -> Corrections:
    """One Corrections from several; ``keep(i, t)`` → bool mask selects samples of item i."""
    sel = [np.ones(len(c.t), bool) if keep is None else keep(i, c.t) for i, c in enumerate(items)]
    return Corrections(*(np.concatenate([getattr(c, f)[m] for c, m in zip(items, sel)]) for f in ("t", "v", "a", "wall_m")),
                       items[0].spacing)


#: Resamples of the camera frames behind the uniform part's standard error.
FRAME_BOOTSTRAP = 400


def _drag_and_uniform(sums: np.ndarray) -> np.ndarray:
    """(c, ux, uy, uz) of a = c (−|v|v) + u by least squares from summed sufficient
    statistics ``sums`` (qq, qx, qy, qz, n, aq, ax, ay, az); NaN where singular."""
    qq, qx, qy, qz, n, aq, ax, ay, az = sums
    A = np.array([[qq, qx, qy, qz], [qx, n, 0, 0], [qy, 0, n, 0], [qz, 0, 0, n]], float)
    b = np.array([aq, ax, ay, az], float)
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return np.full(4, np.nan)


def correction_evidence(c: Corrections, seed: int = 0) -> dict:
    """Drag-like coefficient, uniform part and near-wall slowing of the corrections.

    Drag and the uniform part are fitted together, a = c (−|v|v) + u, so the mean push that
    drag gives a stream flowing one way is not read as wind. The uniform part's t statistic
    resamples whole camera frames (``FRAME_BOOTSTRAP`` times): the corrections of one frame are
    one draw of the tracker, not independent samples (counted one by one, a drag recording's
    512k corrections gave t = 145)."""
    if len(c.v) < 10:
        return {"samples": int(len(c.v))}
    speed = np.linalg.norm(c.v, axis=1, keepdims=True)
    q = -speed * c.v                                         # the drag direction, |v|v
    frames, inv = np.unique(c.t, return_inverse=True)
    per = np.zeros((len(frames), 9))                         # sufficient statistics per frame
    for k, col in enumerate([(q * q).sum(1), q[:, 0], q[:, 1], q[:, 2], np.ones(len(q)),
                             (c.a * q).sum(1), c.a[:, 0], c.a[:, 1], c.a[:, 2]]):
        np.add.at(per[:, k], inv, col)
    fit = _drag_and_uniform(per.sum(0))
    t_stat = None
    if len(frames) >= 5:
        rng = np.random.default_rng(seed)
        boot = np.array([_drag_and_uniform(per[rng.integers(0, len(frames), len(frames))].sum(0))
                         for _ in range(FRAME_BOOTSTRAP)])
        se = np.nanstd(boot[:, [1, 3]], axis=0)
        t_stat = [float(fit[1] / max(se[0], 1e-9)), float(fit[3] / max(se[1], 1e-9))]
    near = c.wall_m < c.spacing
    vhat = c.v / np.maximum(speed, 1e-6)
    slow = -(c.a * vhat).sum(1)
    wall = float(slow[near].mean() - slow[~near].mean()) if near.any() and (~near).any() else None
    return {"samples": int(len(c.v)), "frames": int(len(frames)), "drag_coefficient_per_m": float(fit[0]),
            "uniform_horizontal_m_s2": [float(fit[1]), float(fit[3])],
            "uniform_t_stat": t_stat, "near_wall_slowing_m_s2": wall}


def fit_learned(c: Corrections) -> np.ndarray:
    """(3, 4) W of the minimum-norm correction a = W [v, 1] (ridge; zeros without data)."""
    if len(c.v) < 10:
        return np.zeros((3, 4))
    F = np.concatenate([c.v, np.ones((len(c.v), 1))], 1)
    lam = RIDGE * float((F * F).sum(1).mean()) * len(F)
    W = np.linalg.solve(F.T @ F + lam * np.eye(4), F.T @ c.a).T
    return W
