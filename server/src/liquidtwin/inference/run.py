"""Drive a hypothesis bank through a recording and score it (what ``infer_*`` share).

Time is handled as a session engine handles it (``SessionEngine.advance``): session time is
the pose stamp minus the first; between two pose samples the simulation takes whole dt steps
with the object poses interpolated (lerp/slerp) from the previous sample to the new one, the
sub-step remainder carried over. A mask stamped with a pose sample's time is scored (and,
closed loop, corrects the bank) right after that sample's steps.
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch
from tqdm.auto import tqdm

from ..camera import Camera
from ..recordings._interp import interpolate_poses
from .bank import Bank
from .likelihood import DELTA, SLACK_PX, Posterior, frame_log_likelihood


def camera_at(rec, name: str, t_ns: int) -> Camera:
    """The recording's camera ``name`` posed at ``t_ns`` (its first pose without a series)."""
    info = rec.camera_at(name, t_ns) if name in (rec.camera_poses or {}) else rec.cameras[name]
    return Camera.from_calibration(np.asarray(info.K, float), np.asarray(info.D, float), int(info.width),
                                   int(info.height), torch.tensor(np.array(info.pose, float)), name=name)


def pick_camera(rec, camera: str | None) -> str:
    if not rec.masks:
        raise ValueError("the recording has no liquid masks: inference scores masks")
    if camera is None:
        usable = [c for c in rec.masks if c in rec.cameras]
        if not usable:
            raise ValueError(f"no calibrated camera among the mask cameras {sorted(rec.masks)}")
        return usable[0]
    if camera not in rec.masks or camera not in rec.cameras:
        raise KeyError(f"no masks of a calibrated camera {camera!r} (cameras with masks: {sorted(rec.masks)})")
    return camera


def score(bank: Bank, rec, dt: float, *, camera: str, frames: int | None = None, delta: float = DELTA,
          slack_px: float = SLACK_PX, blur_px: float = 0.0, progress: bool = False,
          desc: str = "hypotheses") -> tuple[np.ndarray, np.ndarray]:
    """Run ``bank`` over ``rec``; returns (per-frame log likelihoods (T, K), frame times (T,) s).
    ``slack_px`` / ``blur_px``: the likelihood's slack or blur at 640×480 (:mod:`.likelihood`;
    both 0: SPEC's exact pixels)."""
    stamps, masks = rec.masks[camera]
    times = np.asarray(rec.pose_times_ns, np.int64)
    n = len(times) if frames is None else min(int(frames), len(times))
    t0 = int(times[0])
    prev = np.asarray(rec.poses[0], np.float64)
    bank.start(torch.as_tensor(prev))
    sim_t, prev_t = 0.0, 0.0
    lls, ts = [], []
    bar = tqdm(total=n, desc=desc, unit="pose", disable=not progress, leave=False)
    for i in range(n):
        t = (int(times[i]) - t0) * 1e-9
        new = np.asarray(rec.poses[i], np.float64)
        steps = max(0, int(math.floor((t - sim_t) / dt + 1e-6)))
        if steps:
            span = t - prev_t
            taus = sim_t + np.arange(1, steps + 1) * dt - prev_t
            frac = np.clip(taus / span if span > 0 else np.ones(steps), 0, 1)
            ns = np.round(frac * 1e9).astype(np.int64)
            path = np.stack([interpolate_poses(np.array([0, 10**9]), np.stack([prev[j], new[j]]), ns)
                             for j in range(len(new))], 1)
            with torch.no_grad():
                for k in range(steps):
                    bank.step(torch.as_tensor(path[k]))
                bank.cull()
            sim_t += steps * dt
        prev, prev_t = new, t
        j = int(np.searchsorted(stamps, times[i]))
        if j < len(stamps) and stamps[j] == times[i]:
            cam = camera_at(rec, camera, int(times[i]))
            with torch.no_grad():
                dis = bank.observe(cam, torch.as_tensor(masks[j]), slack_px, blur_px)
            pixels = int(masks[j].size)
            lls.append([frame_log_likelihood(float(d), pixels, delta) for d in dis])
            ts.append(t)
        bar.update()
    bar.close()
    return np.asarray(lls, np.float64).reshape(-1, bank.K), np.asarray(ts, np.float64)


def run_bank(bank: Bank, rec, dt: float, *, camera: str | None = None, frames: int | None = None,
             delta: float = DELTA, slack_px: float = SLACK_PX, blur_px: float = 0.0, batched: bool = True,
             progress: bool = False, info: dict | None = None) -> Posterior:
    """Score every hypothesis of ``bank`` on ``rec``: all at once (``batched``) or one after
    another (each alone, the sequential baseline). Returns the :class:`Posterior`."""
    camera = pick_camera(rec, camera)
    start = time.perf_counter()
    names = [h.name for h in bank.hypotheses]
    if batched:
        ll, ts = score(bank, rec, dt, camera=camera, frames=frames, delta=delta, slack_px=slack_px, blur_px=blur_px,
                       progress=progress)
    else:
        cols = []
        for k in range(bank.K):
            c, ts = score(bank.single(k), rec, dt, camera=camera, frames=frames, delta=delta, slack_px=slack_px,
                          blur_px=blur_px, progress=progress, desc=names[k])
            cols.append(c)
        ll = np.concatenate(cols, 1)
    extra = {"camera": camera, "tracking": bank.mode, "batched": batched, "delta": delta, "slack_px": float(slack_px),
             "blur_px": float(blur_px),
             "particles": dict(zip(names, bank.counts))} | dict(info or {})
    return Posterior.from_series(names, ll, ts, time.perf_counter() - start, extra)
