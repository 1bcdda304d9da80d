"""Read a recording (ours or any conforming MCAP) as arrays, or stream it as typed events.

Topics are found by schema (see :mod:`liquidtwin.recordings.topics`). Times are the
messages' own stamps in ns (their MCAP log time when a stamp is unset).

Poses: every object's transforms form its own series; ``Recording.poses`` samples all
objects at the union of their stamps, exactly where an object has a sample and otherwise
interpolated (linear translation, slerp rotation; the end poses held outside the series).

Cameras whose pose changes over time: ``Recording.cameras[name]`` holds the pose of the
camera's *first* transform; ``Recording.camera_poses[name]`` holds every pose with its
time, and :meth:`Recording.camera_at` gives the camera at any time (interpolated the same
way). In :func:`iter_messages` each camera transform is its own ``"camera"`` event.

Every failure raises :class:`~liquidtwin.recordings.RecordingError` (a ValueError) naming
the file, the topic and the problem. Stamps must not go backwards within a topic (checked
per frame on transform topics, per camera on image topics). The whole file is checked
(CRCs, order, sizes, topics, masks) before :func:`iter_messages` yields its first event;
only RGB frames are decoded as they are yielded.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Mapping, NamedTuple

import numpy as np
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from liquidtwin_proto import SceneSpec

from ._codec import decode_mask, decode_poses_in_frame, decode_rgb, decode_transforms, stamp_ns
from ._collect import Collection
from ._interp import interpolate_poses
from ._scan import iter_raw
from .base import CameraInfo


@dataclass(frozen=True, eq=False)
class Recording:
    """Measured data of one recording.

    Fields:
      path: the file.
      spec: its ``/scene`` (``liquidtwin.v1.SceneSpec``), or None.
      object_names: the n objects, in the scene's order (or first-seen order without a scene).
      pose_times_ns: (T,) int64 pose sample times, ns.
      poses: (T, n, 7) float64 object → world poses (tx, ty, tz m, qx, qy, qz, qw).
      cameras: {name: CameraInfo} calibration + pose at the camera's first transform.
      camera_poses: {name: ((K,) int64 ns, (K, 7) float64)} every camera → world pose.
      masks: {camera: ((M,) int64 ns, (M, H, W) bool)} liquid masks, True = liquid.
      images: {camera: ((M,) int64 ns, [M × (H, W, 3) uint8 RGB])}; empty if not read.
      duration_s: last minus first stamp of everything read, s.
    """

    path: Path
    spec: SceneSpec | None
    object_names: list[str]
    pose_times_ns: np.ndarray
    poses: np.ndarray
    cameras: dict[str, CameraInfo]
    camera_poses: dict[str, tuple[np.ndarray, np.ndarray]]
    masks: dict[str, tuple[np.ndarray, np.ndarray]]
    images: dict[str, tuple[np.ndarray, list[np.ndarray]]]
    duration_s: float

    def camera_at(self, name: str, t_ns: int) -> CameraInfo:
        """Camera ``name`` with its pose at ``t_ns`` (interpolated between its transforms)."""
        if name not in self.cameras:
            raise KeyError(f"no camera {name!r} in {self.path} (cameras: {sorted(self.cameras)})")
        times, poses = self.camera_poses[name]
        return self.cameras[name].with_pose(interpolate_poses(times, poses, [t_ns])[0])

    def poses_at(self, t_ns: int) -> np.ndarray:
        """(n, 7) object poses at ``t_ns`` (interpolated between pose samples)."""
        return np.stack([interpolate_poses(self.pose_times_ns, self.poses[:, j], [t_ns])[0]
                         for j in range(len(self.object_names))])


class PoseSample(NamedTuple):
    """Payload of a ``"poses"`` event: object names and their (k, 7) poses → world."""

    names: tuple[str, ...]
    poses: np.ndarray


class Event(NamedTuple):
    """One streamed item of a recording.

    kind / payload:
      ``"scene"``: SceneSpec; ``"poses"``: :class:`PoseSample` (the objects one message
      carried); ``"camera"``: CameraInfo (at a calibration message: the pose at that time;
      at a camera transform: that pose); ``"mask"``: (H, W) bool; ``"image"``: (H, W, 3)
      uint8 RGB. ``camera`` is the camera name for the last three kinds, else None.
    """

    kind: str
    t_ns: int
    camera: str | None
    payload: Any


def read_recording(path: str | Path, *, images: bool = True,
                   topics: Mapping[str, str] | None = None) -> Recording:
    """Load a whole recording. ``images=False`` skips RGB frames; ``topics`` maps topic → kind
    ("scene", "poses", "calibration", "mask", "image", "ignore") to override discovery."""
    col = Collection(path, topics, images=images, keep_masks=True, keep_images=images).run()
    names = col.object_names
    times = np.unique(np.concatenate([col.objects[n][0] for n in names]))
    poses = np.empty((len(times), len(names), 7))
    for j, n in enumerate(names):
        poses[:, j] = interpolate_poses(*col.objects[n], times)
    masks = {}
    for camera, items in col.masks.items():
        items = sorted(items, key=lambda it: it[0])
        masks[camera] = (np.array([it[0] for it in items], dtype=np.int64),
                         np.stack([it[1] for it in items]))
    rgb = {}
    for camera, items in col.images.items():
        items = sorted(items, key=lambda it: it[0])
        rgb[camera] = (np.array([it[0] for it in items], dtype=np.int64), [it[1] for it in items])
    duration = 0.0 if col.t_min is None else (col.t_max - col.t_min) * 1e-9
    return Recording(col.path, col.spec, list(names), times, poses, dict(col.cameras),
                     dict(col.camera_poses), masks, rgb, duration)


def iter_messages(path: str | Path, *, images: bool = True,
                  topics: Mapping[str, str] | None = None) -> Iterator[Event]:
    """Stream a recording as :class:`Event` s in log-time order (ties in file order).

    The file is checked completely first (a pass that keeps no masks or images), so a
    damaged recording fails before the first event.
    """
    col = Collection(path, topics, images=images, keep_masks=False, keep_images=False).run()
    objects = set(col.object_names)
    for raw in iter_raw(col.path, log_time_order=True):
        kind = col.kind(raw)
        if kind == "ignore":
            continue
        msg = col.decode(raw)
        if kind == "scene":
            yield Event("scene", raw.log_time, None, msg)
        elif kind == "poses" and isinstance(msg, PosesInFrame):
            t, _, poses = decode_poses_in_frame(msg, raw.log_time)
            yield Event("poses", t, None, PoseSample(tuple(col.object_names), np.array(poses)))
        elif kind == "poses":
            yield from _transform_events(col, objects, decode_transforms(msg, raw.log_time))
        elif kind == "calibration":
            camera = col.image_camera(raw, msg)
            t = stamp_ns(msg, raw.log_time)
            yield Event("camera", t, camera, col.camera_at(camera, t))
        else:
            camera = col.image_camera(raw, msg)
            t = stamp_ns(msg, raw.log_time)
            payload = col.wrap(raw, decode_mask if kind == "mask" else decode_rgb, msg, t=t)
            yield Event(kind, t, camera, payload)


def _transform_events(col: Collection, objects: set[str], items) -> Iterator[Event]:
    by_time = defaultdict(list)
    for t, parent, child, pose in items:
        if parent == col.root and (child in objects or child in col.cameras):
            by_time[t].append((child, pose))
    for t, rows in sorted(by_time.items(), key=lambda kv: kv[0]):
        names = tuple(c for c, _ in rows if c in objects)
        if names:
            poses = np.array([p for c, p in rows if c in objects], dtype=np.float64)
            yield Event("poses", t, None, PoseSample(names, poses))
        for c, p in rows:
            if c in col.cameras:
                yield Event("camera", t, c, col.cameras[c].with_pose(p))
