"""Foxglove / liquidtwin messages as the client sends and receives them.

Inputs (``<prefix>/<session>/in/<stream>``) are Foxglove messages built here from NumPy
arrays; outputs (``<prefix>/<session>/out/<stream>``) arrive as :class:`Output` with the
decoded message. Conventions: SI units, poses (7,) = (tx, ty, tz [m], qx, qy, qz, qw),
object → world (camera → world for cameras, OpenCV camera frame: x right, y down, z forward).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf.timestamp_pb2 import Timestamp
from liquidtwin_proto import Control, Header, Metrics, Volumes

WORLD = "world"
#: Unit-quaternion tolerance the server applies (docs/service.md): | |q| - 1 | ≤ 1e-3.
QUAT_TOL = 1e-3
#: Message class of every stream, inputs and outputs.
STREAM_TYPES = {
    "poses": FrameTransforms, "camera": CameraCalibration, "mask": RawImage,
    "image": CompressedImage, "particles": PointCloud, "volumes": Volumes,
    "control": Control, "overlay": RawImage, "metrics": Metrics,
}
_IMAGE_FORMATS = ("jpeg", "png")


@dataclass(frozen=True)
class Output:
    """One sample of a session's output stream.

    Attributes:
        stream: "particles", "volumes", "control", "overlay" or "metrics".
        header: the sample's liquidtwin Header (``stamp_ns`` = the answered frame's stamp,
            ns since the Unix epoch; ``seq`` = the server's output counter).
        message: the decoded protobuf (foxglove.PointCloud, Volumes, Control,
            foxglove.RawImage or Metrics).
        payload: the message as received, serialized bytes.
        received_ns: wall-clock time the client received it, ns since the Unix epoch.
    """

    stream: str
    header: Header
    message: object
    payload: bytes
    received_ns: int


def timestamp(stamp_ns: int) -> Timestamp:
    """A protobuf Timestamp of ``stamp_ns`` (ns since the Unix epoch)."""
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return Timestamp(seconds=sec, nanos=nsec)


def stamp_of(ts: Timestamp) -> int:
    """ns since the Unix epoch of a protobuf Timestamp."""
    return int(ts.seconds) * 1_000_000_000 + int(ts.nanos)


def check_pose(name: str, pose) -> np.ndarray:
    """``pose`` as a finite (7,) float64 array with a unit quaternion, else ValueError."""
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (7,):
        raise ValueError(f"pose of {name!r} must have shape (7,) = (tx, ty, tz, qx, qy, qz, "
                         f"qw), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"pose of {name!r} holds NaN or infinity: {p.tolist()}")
    norm = float(np.linalg.norm(p[3:]))
    if abs(norm - 1.0) > QUAT_TOL:
        raise ValueError(f"pose of {name!r}: quaternion (qx, qy, qz, qw) has norm {norm:.6f}; "
                         f"it must be a unit quaternion within {QUAT_TOL}")
    return p


def encode_poses(poses: Mapping[str, object], stamp_ns: int) -> FrameTransforms:
    """FrameTransforms (parent ``world``) of ``{name: (7,) pose}``, each child = name."""
    if not isinstance(poses, Mapping) or not poses:
        raise ValueError("poses must be a non-empty mapping {object or camera name: (7,) pose}")
    msg = FrameTransforms()
    for name, pose in poses.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"pose names must be non-empty strings, got {name!r}")
        p = check_pose(name, pose)
        tf = msg.transforms.add(parent_frame_id=WORLD, child_frame_id=name)
        tf.timestamp.CopyFrom(timestamp(stamp_ns))
        tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in p[:3])
        q = tf.rotation
        q.x, q.y, q.z, q.w = (float(v) for v in p[3:])
    return msg


def encode_camera(name: str, K, D, width: int, height: int, stamp_ns: int) -> CameraCalibration:
    """CameraCalibration of a pinhole camera (plumb_bob; R = I, P = [K | 0]).

    Args:
        K: (3, 3) intrinsic matrix, pixels. D: (5,) plumb_bob distortion (k1, k2, p1, p2, k3).
        width, height: image size, pixels.
    """
    k = np.asarray(K, dtype=np.float64)
    d = np.asarray(D, dtype=np.float64).reshape(-1)
    if k.shape != (3, 3):
        raise ValueError(f"camera {name!r}: K must be (3, 3), got shape {k.shape}")
    if d.shape != (5,):
        raise ValueError(f"camera {name!r}: D must hold 5 plumb_bob values, got {d.size}")
    if not (np.all(np.isfinite(k)) and np.all(np.isfinite(d))):
        raise ValueError(f"camera {name!r}: K or D holds NaN or infinity")
    if k[0, 0] <= 0 or k[1, 1] <= 0:
        raise ValueError(f"camera {name!r}: focal lengths K[0,0], K[1,1] must be > 0")
    if int(width) <= 0 or int(height) <= 0:
        raise ValueError(f"camera {name!r}: width and height must be positive, got "
                         f"{width}x{height}")
    p = np.concatenate([k, np.zeros((3, 1))], axis=1)
    msg = CameraCalibration(frame_id=name, width=int(width), height=int(height),
                            distortion_model="plumb_bob", D=d.tolist(), K=k.ravel().tolist(),
                            R=np.eye(3).ravel().tolist(), P=p.ravel().tolist())
    msg.timestamp.CopyFrom(timestamp(stamp_ns))
    return msg


def encode_mask(camera: str, mask, stamp_ns: int) -> RawImage:
    """mono8 RawImage of a liquid mask: (H, W) bool or uint8, nonzero = liquid → 255."""
    m = np.asarray(mask)
    if m.ndim != 2 or 0 in m.shape:
        raise ValueError(f"mask of camera {camera!r} must be a non-empty (H, W) array, "
                         f"got shape {m.shape}")
    if m.dtype != np.bool_ and m.dtype != np.uint8:
        raise ValueError(f"mask of camera {camera!r} must be bool or uint8, got {m.dtype}")
    data = np.where(m != 0, 255, 0).astype(np.uint8)
    h, w = data.shape
    msg = RawImage(frame_id=camera, width=w, height=h, encoding="mono8", step=w,
                   data=data.tobytes())
    msg.timestamp.CopyFrom(timestamp(stamp_ns))
    return msg


def encode_image(camera: str, data: bytes, fmt: str, stamp_ns: int) -> CompressedImage:
    """CompressedImage of an already-compressed RGB frame (``fmt`` "jpeg" or "png")."""
    if fmt not in _IMAGE_FORMATS:
        raise ValueError(f"image format must be one of {_IMAGE_FORMATS}, got {fmt!r}")
    if not isinstance(data, (bytes, bytearray, memoryview)) or len(data) == 0:
        raise ValueError(f"image of camera {camera!r} must be non-empty {fmt} bytes")
    msg = CompressedImage(frame_id=camera, format=fmt, data=bytes(data))
    msg.timestamp.CopyFrom(timestamp(stamp_ns))
    return msg


def decode_particles(cloud: PointCloud) -> tuple[np.ndarray, np.ndarray]:
    """Positions and speeds of a particles PointCloud.

    Returns:
        positions: (N, 3) float32, m, world frame. speed: (N,) float32, m/s (zeros when the
        cloud has no ``speed`` field).

    Raises:
        ValueError: missing x/y/z fields, non-float32 fields or a data length that is not a
            multiple of ``point_stride``.
    """
    fields = {f.name: f for f in cloud.fields}
    for name in ("x", "y", "z"):
        if name not in fields:
            raise ValueError(f"point cloud has no field {name!r} (fields: {sorted(fields)})")
    stride = int(cloud.point_stride)
    if stride <= 0 or len(cloud.data) % stride:
        raise ValueError(f"point cloud data of {len(cloud.data)} bytes is not a whole number "
                         f"of {stride}-byte points")
    wanted = [n for n in ("x", "y", "z", "speed") if n in fields]
    for n in wanted:
        if fields[n].type != PackedElementField.FLOAT32:
            raise ValueError(f"point cloud field {n!r} is not FLOAT32")
        if fields[n].offset + 4 > stride:
            raise ValueError(f"point cloud field {n!r} lies outside the {stride}-byte stride")
    dtype = np.dtype({"names": wanted, "formats": ["<f4"] * len(wanted),
                      "offsets": [fields[n].offset for n in wanted], "itemsize": stride})
    rec = np.frombuffer(cloud.data, dtype=dtype)
    pos = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float32)
    speed = rec["speed"].astype(np.float32) if "speed" in fields else np.zeros(len(rec), np.float32)
    return pos, speed


def decode_output(stream: str, payload: bytes):
    """The protobuf message of output ``stream`` from its bytes (DecodeError when malformed)."""
    msg = STREAM_TYPES[stream]()
    msg.ParseFromString(payload)
    return msg
