"""Per-session buffers of what the live page draws; written by Zenoh callbacks, read by
the render thread. Every method is thread-safe and returns quickly (no I/O, no waits)."""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .decode import CameraIntrinsics, MeshData, Particles

_FPS_WINDOW_S = 2.0  # receive-rate estimate over this many seconds


@dataclass(frozen=True)
class Series:
    """A time series over a window.

    Attributes:
        t: (K,) float64 stamps, s relative to the newest sample (all ≤ 0).
        values: name -> (K,) float64 values (NaN where a sample lacked that name).
    """

    t: np.ndarray
    values: dict[str, np.ndarray]


@dataclass(frozen=True)
class SessionSnapshot:
    """What one session looks like now; arrays are shared, never mutated afterwards.

    Attributes:
        session: session id.
        version: increases with every change to the buffer.
        particles: the newest particle frame, or None.
        particles_stamp_ns: its Header stamp, ns since the Unix epoch.
        frames: particle frames received.
        fps: particle frames received per second over the last 2 s.
        age_s: seconds since the newest particle frame arrived (inf before the first).
        overlay: newest overlay (H, W, 3) uint8, or None; ``overlay_camera`` its frame_id.
        overlay_version: increases with every overlay.
        poses: frame name -> (7,) pose (tx, ty, tz, qx, qy, qz, qw), frame → world, m.
        cameras: camera name -> intrinsics.
        meshes: the scene's meshes, or None until the ``meshes`` RPC answered.
        metrics: the newest Metrics message, or None.
        iou: IOU over the window (values key "iou").
        volumes: container volumes over the window, ml (one key per container).
        rejected: samples this viewer could not decode; ``last_error`` the newest reason.
    """

    session: str
    version: int
    particles: Particles | None
    particles_stamp_ns: int
    frames: int
    fps: float
    age_s: float
    overlay: np.ndarray | None
    overlay_camera: str
    overlay_version: int
    poses: dict
    cameras: dict
    meshes: tuple[MeshData, ...] | None
    metrics: object
    iou: Series
    volumes: Series
    rejected: int
    last_error: str


@dataclass
class _History:
    stamps: deque = field(default_factory=deque)  # ns
    rows: deque = field(default_factory=deque)  # dict name -> float

    def add(self, stamp_ns: int, row: dict, window_s: float) -> None:
        self.stamps.append(stamp_ns)
        self.rows.append(row)
        horizon = stamp_ns - int(window_s * 1e9)
        while self.stamps and self.stamps[0] < horizon:
            self.stamps.popleft()
            self.rows.popleft()

    def series(self) -> Series:
        if not self.stamps:
            return Series(np.zeros(0), {})
        t = (np.asarray(self.stamps, np.int64) - self.stamps[-1]) * 1e-9
        names = sorted({n for row in self.rows for n in row})
        return Series(t, {n: np.array([row.get(n, np.nan) for row in self.rows], np.float64)
                          for n in names})


class SessionBuffer:
    """The newest state and recent history of one session's streams.

    Args:
        session: session id.
        window_s: length of the IOU / volume history kept, s of stamp time.
    """

    def __init__(self, session: str, window_s: float = 30.0):
        self.session = session
        self.window_s = window_s
        self._lock = threading.Lock()
        self._version = 0
        self._particles: Particles | None = None
        self._particles_stamp = 0
        self._frames = 0
        self._rx: deque = deque()  # monotonic receive times of recent particle frames
        self._overlay: np.ndarray | None = None
        self._overlay_camera = ""
        self._overlay_version = 0
        self._poses: dict = {}
        self._cameras: dict = {}
        self._meshes: tuple[MeshData, ...] | None = None
        self._metrics = None
        self._iou = _History()
        self._volumes = _History()
        self._rejected = 0
        self._last_error = ""

    def add_particles(self, stamp_ns: int, particles: Particles, rx_s: float | None = None):
        """Store a particle frame received at monotonic time ``rx_s`` (default: now)."""
        rx_s = time.monotonic() if rx_s is None else rx_s
        with self._lock:
            self._particles, self._particles_stamp = particles, stamp_ns
            self._frames += 1
            self._rx.append(rx_s)
            while self._rx and self._rx[0] < rx_s - _FPS_WINDOW_S:
                self._rx.popleft()
            self._version += 1

    def add_overlay(self, camera: str, image: np.ndarray) -> None:
        """Store an overlay image (H, W, 3) uint8 of ``camera``."""
        with self._lock:
            self._overlay, self._overlay_camera = image, camera
            self._overlay_version += 1
            self._version += 1

    def add_poses(self, poses: dict) -> None:
        """Merge poses (name -> (7,)); frames not named keep their last pose."""
        with self._lock:
            self._poses = {**self._poses, **poses}
            self._version += 1

    def add_camera(self, camera: CameraIntrinsics) -> None:
        """Store (replace) one camera's intrinsics."""
        with self._lock:
            self._cameras = {**self._cameras, camera.name: camera}
            self._version += 1

    def set_meshes(self, meshes: tuple[MeshData, ...]) -> None:
        """Store the scene's meshes (the ``meshes`` RPC reply)."""
        with self._lock:
            self._meshes = meshes
            self._version += 1

    def has_meshes(self) -> bool:
        with self._lock:
            return self._meshes is not None

    def add_metrics(self, stamp_ns: int, metrics) -> None:
        """Store a Metrics message; its IOU (NaN without a mask) joins the history."""
        with self._lock:
            self._metrics = metrics
            self._iou.add(stamp_ns, {"iou": float(metrics.iou)}, self.window_s)
            self._version += 1

    def add_volumes(self, stamp_ns: int, volumes: dict[str, float]) -> None:
        """Store per-container volumes, ml."""
        with self._lock:
            self._volumes.add(stamp_ns, dict(volumes), self.window_s)
            self._version += 1

    def reject(self, reason: str) -> None:
        """Count a sample that could not be decoded."""
        with self._lock:
            self._rejected += 1
            self._last_error = reason
            self._version += 1

    def snapshot(self, now_s: float | None = None) -> SessionSnapshot:
        """A consistent copy of the buffer at monotonic time ``now_s`` (default: now)."""
        now_s = time.monotonic() if now_s is None else now_s
        with self._lock:
            rx = [t for t in self._rx if t >= now_s - _FPS_WINDOW_S]
            fps = (len(rx) - 1) / (rx[-1] - rx[0]) if len(rx) > 1 and rx[-1] > rx[0] else 0.0
            return SessionSnapshot(
                session=self.session, version=self._version, particles=self._particles,
                particles_stamp_ns=self._particles_stamp, frames=self._frames, fps=fps,
                age_s=now_s - self._rx[-1] if self._rx else float("inf"),
                overlay=self._overlay, overlay_camera=self._overlay_camera,
                overlay_version=self._overlay_version, poses=self._poses,
                cameras=self._cameras, meshes=self._meshes, metrics=self._metrics,
                iou=self._iou.series(), volumes=self._volumes.series(),
                rejected=self._rejected, last_error=self._last_error,
            )
