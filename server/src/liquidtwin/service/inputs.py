"""Decode and check the Foxglove samples of a session's input streams (docs/service.md).

Every check runs in the Zenoh callback, before a sample reaches the session: payload size,
the Header attachment, the Foxglove decode, finiteness, unit quaternions (±1e-3), known
object/camera names, mask size and encoding, image decodability. A failure raises
:class:`InputError` whose ``cause`` (a short word) groups it for the rate-limited log.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

# A tiny PNG can claim a huge image: cap what OpenCV decodes (read at the first decode).
os.environ.setdefault("OPENCV_IO_MAX_IMAGE_PIXELS", str(50_000_000))
import cv2  # noqa: E402
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from liquidtwin_proto import Error, Header, WireError, decode_attachment, parse

QUAT_TOL = 1e-3
WORLD = "world"
#: Message class of each input stream.
INPUT_TYPES = {"poses": FrameTransforms, "camera": CameraCalibration, "mask": RawImage, "image": CompressedImage}
_IMAGE_FORMATS = {"jpeg": "jpeg", "jpg": "jpeg", "png": "png"}


class InputError(WireError):
    """An input sample the session refuses. ``cause``: short grouping word for logs."""

    def __init__(self, message: str, cause: str, code: int = Error.BAD_REQUEST):
        super().__init__(message, code)
        self.cause = cause


@dataclass
class PosesIn:
    """A frame. objects/cameras: name → (7,) float64 pose (object/camera → world)."""

    objects: dict
    cameras: dict


@dataclass
class CameraIn:
    """A calibration: K (3, 3) px, D (5,) plumb_bob, width/height px."""

    name: str
    K: np.ndarray
    D: np.ndarray
    width: int
    height: int


@dataclass
class MaskIn:
    """An observed liquid mask: (H, W) bool, True = liquid."""

    camera: str
    mask: np.ndarray


@dataclass
class ImageIn:
    """A decoded RGB image (H, W, 3) uint8 (kept for perception; logged, not simulated)."""

    camera: str
    rgb: np.ndarray


@dataclass
class Sample:
    """A checked input sample: the sender's header, the stream, the decoded content, the raw
    payload (logged unchanged) and the ordering key (stream, or stream/camera)."""

    header: Header
    stream: str
    item: object
    payload: bytes

    @property
    def order_key(self) -> str:
        name = getattr(self.item, "camera", None) or getattr(self.item, "name", None)
        return f"{self.stream}/{name}" if self.stream != "poses" and name else self.stream


def _finite(values, what: str) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64)
    if not np.isfinite(a).all():
        raise InputError(f"{what} holds NaN or infinity", "non_finite", Error.NON_FINITE)
    return a


def _pose(tf, what: str) -> np.ndarray:
    t, q = tf.translation, tf.rotation
    p = _finite([t.x, t.y, t.z, q.x, q.y, q.z, q.w], what)
    norm = float(np.linalg.norm(p[3:]))
    if abs(norm - 1.0) > QUAT_TOL:
        raise InputError(f"{what}: quaternion norm is {norm:.6g}, it must be 1 within {QUAT_TOL}", "quaternion")
    return p


class InputChecker:
    """Checks one session's input samples against its scene.

    Args:
      objects: the scene's object names.
      cameras: camera name → (height, width) px, or None while its size is unknown; grows
        as calibrations are accepted (:meth:`learn`).
      max_payload: largest payload accepted, bytes.
    """

    def __init__(self, objects, cameras: dict, max_payload: int):
        self.objects = tuple(objects)
        self.cameras = dict(cameras)
        self.max_payload = int(max_payload)

    def check(self, session_id: str, stream: str, payload: bytes, attachment: bytes | None) -> Sample:
        """The checked :class:`Sample`; InputError otherwise."""
        if stream not in INPUT_TYPES:
            raise InputError(f"unknown input stream {stream!r}", "stream")
        if len(payload) > self.max_payload:
            raise InputError(f"{stream} sample of {len(payload)} bytes is over the server's limit of "
                             f"{self.max_payload}", "too_large", Error.TOO_LARGE)
        try:
            header = decode_attachment(attachment, session_id)
        except WireError as exc:
            raise InputError(str(exc), "header", exc.code) from None
        if header.stamp_ns <= 0:
            raise InputError(f"header stamp_ns must be > 0 (ns since the Unix epoch), got {header.stamp_ns}", "header")
        return Sample(header, stream, self.decode(stream, payload), bytes(payload))

    def decode(self, stream: str, payload: bytes):
        """The checked item of one payload of ``stream`` (no header): PosesIn, CameraIn, MaskIn
        or ImageIn; InputError otherwise. Also used to read a session's log back."""
        if stream not in INPUT_TYPES:
            raise InputError(f"unknown input stream {stream!r}", "stream")
        try:
            msg = parse(INPUT_TYPES[stream], payload, max_bytes=self.max_payload)
        except WireError as exc:
            raise InputError(str(exc), "decode", exc.code) from None
        return getattr(self, f"_{stream}")(msg)

    def learn(self, cam: CameraIn) -> None:
        """Remember an accepted calibration's size (masks of that camera must match it)."""
        self.learn_size(cam.name, cam.height, cam.width)

    def learn_size(self, name: str, height: int, width: int) -> None:
        """Camera ``name``'s image size, px (from a calibration or the session spec)."""
        self.cameras[name] = (int(height), int(width))

    # ------------------------------------------------------------------ streams
    def _poses(self, msg: FrameTransforms) -> PosesIn:
        if not len(msg.transforms):
            raise InputError("poses sample holds no transforms", "empty")
        objects, cameras = {}, {}
        for tf in msg.transforms:
            name = tf.child_frame_id
            if tf.parent_frame_id != WORLD:
                raise InputError(f"transform of {name!r} has parent {tf.parent_frame_id!r}; poses are "
                                 f"object/camera → {WORLD!r}", "parent")
            if name in objects or name in cameras:
                raise InputError(f"poses sample names {name!r} twice", "duplicate")
            if name in self.objects:
                objects[name] = _pose(tf, f"pose of object {name!r}")
            elif name in self.cameras:
                cameras[name] = _pose(tf, f"pose of camera {name!r}")
            else:
                raise InputError(f"poses sample names {name!r}, which is neither an object of the scene "
                                 f"({', '.join(self.objects)}) nor a known camera ({', '.join(sorted(self.cameras))})",
                                 "unknown_name", Error.UNKNOWN_NAME)
        return PosesIn(objects, cameras)

    def _camera(self, msg: CameraCalibration) -> CameraIn:
        name = msg.frame_id
        if not name or name in self.objects or name == WORLD:
            raise InputError(f"calibration frame_id {name!r} must be a camera name (not empty, not an "
                             f"object, not {WORLD!r})", "unknown_name", Error.UNKNOWN_NAME)
        k = _finite(msg.K, f"camera {name!r} K")
        d = _finite(msg.D, f"camera {name!r} D")
        if k.size != 9:
            raise InputError(f"camera {name!r}: K must hold 9 values (3×3 row-major), got {k.size}", "calibration")
        if d.size not in (0, 4, 5):
            raise InputError(f"camera {name!r}: D must hold 5 plumb_bob values, got {d.size}", "calibration")
        if not (k[0] > 0 and k[4] > 0):
            raise InputError(f"camera {name!r}: focal lengths K[0], K[4] must be > 0", "calibration")
        if not (0 < msg.width <= 16384 and 0 < msg.height <= 16384):
            raise InputError(f"camera {name!r}: size {msg.width}×{msg.height} px is not a camera's", "calibration")
        return CameraIn(name, k.reshape(3, 3), np.concatenate([d, np.zeros(5 - d.size)]), int(msg.width), int(msg.height))

    def _known_camera(self, name: str, stream: str) -> tuple | None:
        if name not in self.cameras:
            raise InputError(f"{stream} of unknown camera {name!r} (known: {', '.join(sorted(self.cameras)) or 'none'}); "
                             f"send its calibration first", "unknown_name", Error.UNKNOWN_NAME)
        return self.cameras[name]

    def _mask(self, msg: RawImage) -> MaskIn:
        name = msg.frame_id
        size = self._known_camera(name, "mask")
        if size is None:
            raise InputError(f"mask of camera {name!r} before its calibration (size unknown)", "size")
        if msg.encoding != "mono8":
            raise InputError(f"mask encoding must be mono8, got {msg.encoding!r}", "encoding")
        if (msg.height, msg.width) != tuple(size):
            raise InputError(f"mask of camera {name!r} is {msg.width}×{msg.height} px, its calibration says "
                             f"{size[1]}×{size[0]}", "size")
        step = msg.step or msg.width
        if step < msg.width or len(msg.data) != step * msg.height:
            raise InputError(f"mask data holds {len(msg.data)} bytes; {msg.height} rows of step {step} "
                             f"(>= width {msg.width}) expected", "size")
        rows = np.frombuffer(msg.data, np.uint8).reshape(msg.height, step)
        return MaskIn(name, rows[:, :msg.width] != 0)

    def _image(self, msg: CompressedImage) -> ImageIn:
        name = msg.frame_id
        size = self._known_camera(name, "image")
        fmt = _IMAGE_FORMATS.get(msg.format.lower())
        if fmt is None:
            raise InputError(f"image format must be jpeg or png, got {msg.format!r}", "encoding")
        bgr = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_COLOR) if len(msg.data) else None
        if bgr is None:
            raise InputError(f"image of camera {name!r} does not decode as {fmt}", "image_decode")
        if size is not None and bgr.shape[:2] != tuple(size):
            raise InputError(f"image of camera {name!r} is {bgr.shape[1]}×{bgr.shape[0]} px, its calibration says "
                             f"{size[1]}×{size[0]}", "size")
        return ImageIn(name, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


def session_seconds(stamp_ns: int, first_ns: int) -> float:
    """Session time of a frame stamp, s since the first frame (docs/service.md)."""
    t = (int(stamp_ns) - int(first_ns)) / 1e9
    return t if math.isfinite(t) else 0.0
