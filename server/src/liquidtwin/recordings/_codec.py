"""Foxglove protobuf messages ⇄ numpy: transforms, camera calibration, masks, RGB images.

Decoders raise ValueError with a short reason; the reader adds file, topic and time.
"""

from __future__ import annotations

import cv2
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp
from liquidtwin_proto import SceneSpec

from .base import CameraInfo

#: Message classes by schema name.
CLASSES = {cls.DESCRIPTOR.full_name: cls for cls in (
    SceneSpec, FrameTransforms, FrameTransform, PosesInFrame, CameraCalibration, RawImage,
    CompressedImage)}

_JPEG_QUALITY = 95
_MONO = {"mono8": np.uint8, "8uc1": np.uint8, "mono16": np.uint16, "16uc1": np.uint16,
         "32fc1": np.float32}
_COLOR = {"rgb8": (3, False), "bgr8": (3, True), "rgba8": (4, False), "bgra8": (4, True)}


def timestamp(ns: int) -> Timestamp:
    return Timestamp(seconds=ns // 1_000_000_000, nanos=ns % 1_000_000_000)


def stamp_ns(msg, log_time: int) -> int:
    """Nanoseconds of a message's ``timestamp``; its log time when the stamp is unset (0)."""
    ts = msg.timestamp
    if ts.seconds == 0 and ts.nanos == 0:
        return int(log_time)
    ns = ts.seconds * 1_000_000_000 + ts.nanos
    if ns < 0:
        raise ValueError(f"negative timestamp {ns} ns")
    return ns


# ------------------------------------------------------------------ encoding (writer)

def encode_transforms(t_ns: int, names, poses: np.ndarray, parent: str) -> FrameTransforms:
    """``parent`` → ``names[j]`` per row of (n, 7) float64 poses, stored exactly as given."""
    ts = timestamp(t_ns)
    out = FrameTransforms()
    for name, p in zip(names, poses.tolist()):
        out.transforms.append(FrameTransform(
            timestamp=ts, parent_frame_id=parent, child_frame_id=name,
            translation=Vector3(x=p[0], y=p[1], z=p[2]),
            rotation=Quaternion(x=p[3], y=p[4], z=p[5], w=p[6])))
    return out


def encode_calibration(info: CameraInfo, t_ns: int) -> CameraCalibration:
    P = np.zeros((3, 4))
    P[:, :3] = info.K
    return CameraCalibration(
        timestamp=timestamp(t_ns), frame_id=info.name, width=info.width, height=info.height,
        distortion_model="plumb_bob", D=info.D.tolist(), K=info.K.ravel().tolist(),
        R=np.eye(3).ravel().tolist(), P=P.ravel().tolist())


def encode_mask(camera: str, t_ns: int, mask: np.ndarray) -> RawImage:
    h, w = mask.shape
    data = np.where(mask, np.uint8(255), np.uint8(0)).tobytes()
    return RawImage(timestamp=timestamp(t_ns), frame_id=camera, width=w, height=h,
                    encoding="mono8", step=w, data=data)


def encode_image(camera: str, t_ns: int, rgb: np.ndarray, fmt: str) -> CompressedImage:
    bgr = np.ascontiguousarray(rgb[:, :, ::-1])
    params = [cv2.IMWRITE_JPEG_QUALITY, _JPEG_QUALITY] if fmt == "jpeg" else []
    ok, buf = cv2.imencode(".jpg" if fmt == "jpeg" else ".png", bgr, params)
    if not ok:
        raise ValueError(f"OpenCV could not encode a {rgb.shape} image as {fmt}")
    return CompressedImage(timestamp=timestamp(t_ns), frame_id=camera, data=buf.tobytes(),
                           format=fmt)


# ------------------------------------------------------------------ decoding (reader)

def _pose(translation, rotation) -> list[float]:
    return [translation.x, translation.y, translation.z,
            rotation.x, rotation.y, rotation.z, rotation.w]


def decode_transforms(msg, log_time: int) -> list[tuple[int, str, str, list[float]]]:
    """(t_ns, parent, child, pose (7,)) per transform of a FrameTransforms / FrameTransform."""
    items = msg.transforms if isinstance(msg, FrameTransforms) else [msg]
    return [(stamp_ns(tr, log_time), tr.parent_frame_id, tr.child_frame_id,
             _pose(tr.translation, tr.rotation)) for tr in items]


def decode_poses_in_frame(msg: PosesInFrame, log_time: int) -> tuple[int, str, list[list[float]]]:
    """(t_ns, frame id, poses) of a PosesInFrame."""
    poses = [_pose(p.position, p.orientation) for p in msg.poses]
    return stamp_ns(msg, log_time), msg.frame_id, poses


def decode_calibration(msg: CameraCalibration, pose) -> CameraInfo:
    """CameraInfo of a CameraCalibration (plumb bob, or no distortion) at ``pose`` (7,)."""
    model = msg.distortion_model
    D = np.asarray(msg.D, dtype=np.float64)
    if model not in ("plumb_bob", "rational_polynomial", "") or (model == "" and D.any()):
        raise ValueError(f"distortion model {model!r} is not supported (use plumb_bob)")
    if D.size > 5 and D[5:].any():
        raise ValueError(f"{D.size} distortion coefficients with non-zero terms beyond k3; "
                         "only plumb_bob (k1, k2, p1, p2, k3) is supported")
    D5 = np.zeros(5)
    D5[:min(5, D.size)] = D[:5]
    if len(msg.K) != 9:
        raise ValueError(f"K has {len(msg.K)} values, expected 9 (row-major 3x3)")
    return CameraInfo(msg.frame_id, msg.width, msg.height, np.reshape(msg.K, (3, 3)), D5, pose)


def _raw_array(msg: RawImage, dtype, channels: int) -> np.ndarray:
    itemsize = np.dtype(dtype).itemsize
    row = msg.width * channels * itemsize
    step = msg.step or row
    if msg.width == 0 or msg.height == 0:
        raise ValueError(f"image size {msg.width}x{msg.height} is empty")
    if step < row or len(msg.data) < step * (msg.height - 1) + row:
        raise ValueError(f"{len(msg.data)} data bytes do not hold {msg.height} rows of "
                         f"{msg.width}x{channels} {np.dtype(dtype).name} (step {step})")
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    rows = np.lib.stride_tricks.as_strided(buf, (msg.height, row), (step, 1))
    return rows.copy().view(np.dtype(dtype).newbyteorder("<")).reshape(
        msg.height, msg.width, channels)


def _compressed(msg: CompressedImage, flag: int) -> np.ndarray:
    fmt = msg.format.lower()
    if "png" not in fmt and "jpeg" not in fmt and "jpg" not in fmt:
        raise ValueError(f"compressed format {msg.format!r} is not supported (png or jpeg)")
    img = cv2.imdecode(np.frombuffer(msg.data, dtype=np.uint8), flag)
    if img is None:
        raise ValueError(f"OpenCV cannot decode the {msg.format!r} data ({len(msg.data)} bytes)")
    return img


def decode_mask(msg) -> np.ndarray:
    """(H, W) bool liquid mask. 8/16-bit masks: liquid above half range (0/255, 0/65535), or
    above 0 when the frame's maximum is 1 (0/1 masks); float masks: above 0.5."""
    if isinstance(msg, CompressedImage):
        img = _compressed(msg, cv2.IMREAD_GRAYSCALE)
    else:
        enc = msg.encoding.lower()
        if enc not in _MONO:
            raise ValueError(f"mask encoding {msg.encoding!r} is not supported; masks must be "
                             f"single-channel: {sorted(_MONO)}")
        img = _raw_array(msg, _MONO[enc], 1)[:, :, 0]
    if img.dtype == np.float32:
        return img > 0.5
    if img.max(initial=0) <= 1:
        return img > 0
    return img > np.iinfo(img.dtype).max // 2


def decode_rgb(msg) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a RawImage (rgb8, bgr8, rgba8, bgra8, mono8) or png/jpeg."""
    if isinstance(msg, CompressedImage):
        return np.ascontiguousarray(_compressed(msg, cv2.IMREAD_COLOR)[:, :, ::-1])
    enc = msg.encoding.lower()
    if enc in ("mono8", "8uc1"):
        return np.repeat(_raw_array(msg, np.uint8, 1), 3, axis=2)
    if enc not in _COLOR:
        raise ValueError(f"image encoding {msg.encoding!r} is not supported "
                         f"({sorted(_COLOR) + ['mono8']})")
    channels, bgr = _COLOR[enc]
    img = _raw_array(msg, np.uint8, channels)[:, :, :3]
    return np.ascontiguousarray(img[:, :, ::-1] if bgr else img)
