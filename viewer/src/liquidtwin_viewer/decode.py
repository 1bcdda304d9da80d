"""Payloads of a liquidtwin session's streams and RPC replies as NumPy values.

Pure functions (no Zenoh, no viser): each takes the bytes of one sample and returns what
the live page draws, or raises :class:`StreamError` with a message saying what is wrong.
Schemas are those of docs/service.md: Foxglove messages for particles, poses, camera
calibration and overlay images, liquidtwin's own for metrics, volumes and meshes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from liquidtwin_proto import (
    ArrayError,
    Metrics,
    SceneMeshes,
    Volumes,
    WireError,
    parse,
    unpack_array,
)

from .pointclouds import RecordingError, read_cloud

WORLD_FRAME = "world"


class StreamError(ValueError):
    """A stream sample or RPC reply the viewer cannot show."""


@dataclass(frozen=True)
class Particles:
    """One particle frame.

    Attributes:
        points: (N, 3) float32 positions in the world frame, m.
        speed: (N,) float32 speeds, m/s (NaN where the cloud has no ``speed`` field).
    """

    points: np.ndarray
    speed: np.ndarray


@dataclass(frozen=True)
class CameraIntrinsics:
    """A camera's calibration (foxglove.CameraCalibration).

    Attributes:
        name: camera name (the calibration's frame_id).
        width, height: image size, pixels.
        k: (3, 3) float64 intrinsic matrix, pixels.
    """

    name: str
    width: int
    height: int
    k: np.ndarray

    @property
    def fov_y(self) -> float:
        """Vertical field of view, rad."""
        return 2.0 * math.atan2(self.height / 2.0, float(self.k[1, 1]))

    @property
    def aspect(self) -> float:
        """Width over height of the image."""
        return self.width / self.height


@dataclass(frozen=True)
class MeshData:
    """One object's surface from the ``meshes`` RPC.

    Attributes:
        name: object name (child frame of its poses).
        vertices: (V, 3) float32 vertices in the object frame, m.
        faces: (F, 3) uint32 vertex indices.
        container: the object holds liquid.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    container: bool


def decode_particles(payload: bytes) -> Particles:
    """A ``particles`` sample (foxglove.PointCloud in frame "world", fields x, y, z, speed)."""
    cloud = _parse(PointCloud, payload)
    if cloud.frame_id and cloud.frame_id != WORLD_FRAME:
        raise StreamError(f"particles are in frame {cloud.frame_id!r}; expected {WORLD_FRAME!r}")
    try:
        points, fields = read_cloud(cloud, ("speed",))
    except RecordingError as exc:
        raise StreamError(f"bad particles point cloud: {exc}") from None
    return Particles(points, fields["speed"])


def decode_overlay(payload: bytes) -> tuple[str, np.ndarray]:
    """An ``overlay`` sample (foxglove.RawImage rgb8).

    Returns:
        (camera name, (H, W, 3) uint8 RGB image).
    """
    image = _parse(RawImage, payload)
    if image.encoding != "rgb8":
        raise StreamError(f"overlay encoding is {image.encoding!r}; expected 'rgb8'")
    w, h = image.width, image.height
    step = image.step or 3 * w
    if w == 0 or h == 0:
        raise StreamError(f"overlay image is {w}x{h} pixels")
    if step < 3 * w or len(image.data) < step * (h - 1) + 3 * w:
        raise StreamError(f"overlay {w}x{h} rgb8 with step {step} needs "
                          f"{step * (h - 1) + 3 * w} bytes, has {len(image.data)}")
    rows = np.frombuffer(image.data, np.uint8, count=step * (h - 1) + 3 * w)
    rows = np.lib.stride_tricks.as_strided(rows, (h, w, 3), (step, 3, 1))
    return image.frame_id, np.ascontiguousarray(rows)


def decode_poses(payload: bytes) -> dict[str, np.ndarray]:
    """A ``poses`` sample (foxglove.FrameTransforms, parent "world").

    Returns:
        child frame name -> (7,) float64 pose (tx, ty, tz, qx, qy, qz, qw), child → world,
        quaternion normalised. Transforms with another parent are skipped.

    Raises:
        StreamError: a non-finite value or a zero quaternion.
    """
    msg = _parse(FrameTransforms, payload)
    poses = {}
    for tf in msg.transforms:
        if tf.parent_frame_id not in ("", WORLD_FRAME):
            continue
        t, q = tf.translation, tf.rotation
        pose = np.array([t.x, t.y, t.z, q.x, q.y, q.z, q.w], np.float64)
        norm = float(np.linalg.norm(pose[3:]))
        if not np.isfinite(pose).all() or norm < 1e-6:
            raise StreamError(f"pose of {tf.child_frame_id!r} is not finite or has a zero "
                              f"quaternion: {pose.tolist()}")
        pose[3:] /= norm
        poses[tf.child_frame_id] = pose
    return poses


def decode_camera(payload: bytes) -> CameraIntrinsics:
    """A ``camera`` sample (foxglove.CameraCalibration)."""
    cal = _parse(CameraCalibration, payload)
    if cal.width == 0 or cal.height == 0 or len(cal.K) != 9:
        raise StreamError(f"camera {cal.frame_id!r}: need width, height > 0 and 9 K values; "
                          f"got {cal.width}x{cal.height}, {len(cal.K)} values")
    k = np.asarray(cal.K, np.float64).reshape(3, 3)
    if not np.isfinite(k).all() or k[0, 0] <= 0 or k[1, 1] <= 0:
        raise StreamError(f"camera {cal.frame_id!r}: focal lengths must be positive and "
                          f"finite; K = {k.ravel().tolist()}")
    return CameraIntrinsics(cal.frame_id, int(cal.width), int(cal.height), k)


def decode_meshes(payload: bytes) -> tuple[MeshData, ...]:
    """A ``meshes`` RPC reply (SceneMeshes)."""
    msg = _parse(SceneMeshes, payload)
    out = []
    for obj in msg.objects:
        try:
            v = unpack_array(obj.vertices, require_finite=True)
            f = unpack_array(obj.faces)
        except ArrayError as exc:
            raise StreamError(f"mesh {obj.name!r}: {exc}") from None
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
            raise StreamError(f"mesh {obj.name!r}: vertices {v.shape} and faces {f.shape} "
                              "must be (V, 3) and (F, 3)")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise StreamError(f"mesh {obj.name!r}: face index out of range 0..{len(v) - 1}")
        out.append(MeshData(obj.name, v.astype(np.float32), f.astype(np.uint32), obj.container))
    return tuple(out)


def decode_metrics(payload: bytes) -> Metrics:
    """A ``metrics`` sample (liquidtwin Metrics)."""
    return _parse(Metrics, payload)


def decode_volumes(payload: bytes) -> dict[str, float]:
    """A ``volumes`` sample (liquidtwin Volumes): container name -> ml."""
    return {c.name: float(c.ml) for c in _parse(Volumes, payload).containers}


def _parse(cls, payload: bytes):
    try:
        return parse(cls, payload)
    except WireError as exc:
        raise StreamError(str(exc)) from None
