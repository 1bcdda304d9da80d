"""What the discrepancy analysis reads: one recording's masks and poses, nothing else.

An :class:`Episode` is a recording reduced to the data the analysis may use — the scene it
states, the object poses, one camera's stated calibration and its liquid masks — on a session
clock (first pose sample = 0 s). Truth sidecars are never opened here.

The poses are smoothed on loading (:data:`POSE_SMOOTHING_S`): the analysis is offline, so a
zero-phase filter costs no lag, and a tracker's white jitter, differenced by the simulator
into container velocities, shakes the model's liquid — energy that drag and viscosity fits
would then take out (measured: README, "Discrepancy discovery").
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..camera import Camera
from ..recordings import read_recording
from ..recordings._interp import POSE_SMOOTHING_S, interpolate_poses, pose_noise_level, smooth_poses
from ..sensors.poses import PoseNoise, noisy_poses


@dataclass(frozen=True, eq=False)
class Episode:
    """One recording, as the analysis sees it.

    Attributes:
      path: the MCAP file. spec: its scene as a SessionSpec (stated fills, objects, sim).
      object_names: n objects in the scene's order.
      pose_t: (T,) s pose sample times; poses: (T, n, 7) object → world poses (smoothed).
      camera: the stated :class:`Camera` the masks came from.
      frame_t: (M,) s mask times; masks: (M, H, W) bool observed liquid.
      pose_noise: (n, 2) the tracker's white noise per object, estimated from the raw poses
        (position std per axis m, rotation std per axis rad: ``pose_noise_level``).
      smoothing_s: the σ the poses were smoothed with, s.
    """

    path: Path
    spec: pb.SessionSpec
    object_names: tuple
    pose_t: np.ndarray
    poses: np.ndarray
    camera: Camera
    frame_t: np.ndarray
    masks: np.ndarray
    pose_noise: np.ndarray
    smoothing_s: float

    @property
    def duration_s(self) -> float:
        return float(self.pose_t[-1])

    def poses_at(self, t: np.ndarray, poses: np.ndarray | None = None) -> np.ndarray:
        """(len(t), n, 7) object poses at session times ``t`` s (lerp/slerp, held at the ends)
        of the episode's pose series, or of another one ``poses`` on the same sample times."""
        poses = self.poses if poses is None else poses
        ns = np.round(np.clip(np.asarray(t, float), 0.0, self.pose_t[-1]) * 1e9).astype(np.int64)
        times = np.round(self.pose_t * 1e9).astype(np.int64)
        return np.stack([interpolate_poses(times, poses[:, j], ns) for j in range(poses.shape[1])], 1)

    def redrawn_poses(self, rng: np.random.Generator, drift: float, drift_s: float) -> np.ndarray:
        """(T, n, 7): the poses as another run of the same tracker could have reported them.
        Fresh tracker noise — white at the level estimated from the recording
        (``pose_noise``), plus a slow drift of ``drift`` × that level with correlation time
        ``drift_s`` s (one recording cannot tell a drift from the motion, so its size is
        assumed) — is added to the (smoothed) poses, and smoothed as on loading. The
        difference from :attr:`poses` is an error of the size the model's own poses carry."""
        rate = (len(self.pose_t) - 1) / max(self.duration_s, 1e-9)
        out = np.empty_like(self.poses)
        for j, (pos, rot) in enumerate(self.pose_noise):
            pos, rot = min(float(pos), 0.1), min(float(rot), 0.5)           # PoseNoise's ranges
            noise = PoseNoise(pos_sigma_m=pos, rot_sigma_rad=rot, drift_m=min(drift * pos, 0.1),
                              drift_rad=min(drift * rot, 0.5), drift_frames=float(np.clip(drift_s * rate, 1.0, 1e6)))
            out[:, j] = noisy_poses(self.poses[:, j], rng, noise)
        return smooth_poses(self.pose_t, out, self.smoothing_s)


def camera_from_info(info, name: str = "camera") -> Camera:
    """A :class:`Camera` from a recording's CameraInfo (K, D, size, pose)."""
    K = np.asarray(info.K, float).reshape(3, 3)
    return Camera(width=int(info.width), height=int(info.height), fx=float(K[0, 0]), fy=float(K[1, 1]),
                  cx=float(K[0, 2]), cy=float(K[1, 2]), pose=torch.tensor(np.asarray(info.pose, float)),
                  distortion=torch.tensor(np.asarray(info.D, float)), name=name)


def load_episode(source, camera: str | None = None, smoothing_s: float = POSE_SMOOTHING_S) -> Episode:
    """An :class:`Episode` from an MCAP path or a Recording (``camera``: default the first
    with masks; ``smoothing_s``: the poses' smoothing σ, 0 for the raw poses). Raises
    ValueError when the recording cannot be analysed."""
    rec = read_recording(source, images=False) if isinstance(source, (str, Path)) else source
    if rec.spec is None:
        raise ValueError(f"{rec.path}: no /scene in the recording; the model cannot be built")
    if not rec.masks:
        raise ValueError(f"{rec.path}: no liquid masks in the recording; there is nothing to compare with")
    camera = camera or next(iter(rec.masks))
    if camera not in rec.masks:
        raise ValueError(f"{rec.path}: no masks from camera {camera!r} (cameras with masks: {sorted(rec.masks)})")
    if len(rec.pose_times_ns) < 2:
        raise ValueError(f"{rec.path}: fewer than 2 pose samples")
    t0 = int(rec.pose_times_ns[0])
    stamps, masks = rec.masks[camera]
    keep = (stamps >= t0) & (stamps <= int(rec.pose_times_ns[-1]))
    if not keep.any():
        raise ValueError(f"{rec.path}: no mask of camera {camera!r} lies within the pose samples")
    info = rec.camera_at(camera, int(stamps[keep][0]))
    pose_t = (rec.pose_times_ns - t0) * 1e-9
    raw = np.asarray(rec.poses, float)
    return Episode(Path(rec.path), pb.SessionSpec(scene=rec.spec), tuple(rec.object_names),
                   pose_t, smooth_poses(pose_t, raw, smoothing_s), camera_from_info(info, camera),
                   (stamps[keep] - t0) * 1e-9, np.asarray(masks[keep], bool), pose_noise_level(raw), float(smoothing_s))
