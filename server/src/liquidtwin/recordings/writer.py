"""Write measured data (object poses, cameras, liquid masks, RGB) to an MCAP recording.

Layout: see :mod:`liquidtwin.recordings.topics`. The file is byte-for-byte deterministic:
nothing reads the clock, protobuf is serialised deterministically, and the MCAP header
names only this library.

>>> with RecordingWriter("pour.mcap", spec) as rec:
...     rec.write_camera("cam0", info, t_ns=0)
...     rec.write_poses(0, ["cup", "bowl"], poses)          # (2, 7)
...     rec.write_mask("cam0", 0, mask)                      # (H, W) bool
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from liquidtwin_proto import SceneSpec
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from .base import (CameraInfo, as_numpy, check_camera_name, check_object_name, check_poses,
                   WRITE_QUAT_TOL)
from ._codec import encode_calibration, encode_image, encode_mask, encode_transforms
from .topics import SCENE_TOPIC, TF_TOPIC, WORLD_FRAME, camera_topic

#: MCAP header "library" field: fixed, so identical content gives identical bytes.
LIBRARY = "liquidtwin.recordings/1"
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}


def _descriptor_set(cls) -> bytes:
    """The FileDescriptorSet of a generated message class, dependencies first."""
    out, seen = FileDescriptorSet(), set()

    def add(fd):
        for dep in fd.dependencies:
            if dep.name not in seen:
                seen.add(dep.name)
                add(dep)
        fd.CopyToProto(out.file.add())

    add(cls.DESCRIPTOR.file)
    return out.SerializeToString(deterministic=True)


def _stamp(t_ns) -> int:
    if isinstance(t_ns, (bool, np.bool_)) or not isinstance(t_ns, (int, np.integer)):
        raise ValueError(f"t_ns must be an integer number of nanoseconds, got {t_ns!r}")
    if not 0 <= t_ns < 2**63:
        raise ValueError(f"t_ns must be in [0, 2**63) ns, got {t_ns}")
    return int(t_ns)


class RecordingWriter:
    """Context manager writing one MCAP recording (see :mod:`~liquidtwin.recordings.topics`).

    Args:
      path: output file (parent directories are created; an existing file is replaced).
      spec: the scene (``liquidtwin.v1.SceneSpec``) or None. When its ``objects`` / ``cameras``
        lists are non-empty, poses and cameras must use those names.
      compression: chunk compression, "zstd" (default), "lz4" or "none".
      start_ns: stamp of ``/scene`` and earliest stamp allowed; default: the first stamp
        written.
      chunk_size: uncompressed bytes per MCAP chunk.

    Stamps are integer ns; they must not go backwards within a topic (equal is fine).
    Errors in the input raise ValueError before anything is written.
    """

    def __init__(self, path: str | Path, spec: SceneSpec | None, *, compression: str = "zstd",
                 start_ns: int | None = None, chunk_size: int = 1 << 20):
        if spec is not None and not isinstance(spec, SceneSpec):
            raise TypeError(f"spec must be a liquidtwin_proto.SceneSpec or None, "
                            f"got {type(spec).__name__}")
        if compression not in _COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(_COMPRESSION)}, "
                             f"got {compression!r}")
        self.path = Path(path)
        self._spec = None if spec is None else SceneSpec.FromString(spec.SerializeToString())
        self._objects = {o.name for o in spec.objects} if spec is not None else set()
        self._spec_cameras = set(spec.cameras) if spec is not None else set()
        self._start = None if start_ns is None else _stamp(start_ns)
        self._cameras: dict[str, CameraInfo] = {}
        self._object_names: set[str] = set()
        self._last: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")
        self._mcap = Writer(self._file, chunk_size=chunk_size,
                            compression=_COMPRESSION[compression], enable_crcs=True,
                            enable_data_crcs=True)
        self._mcap.start(profile="", library=LIBRARY)
        if self._start is not None:
            self._write_scene()

    # ------------------------------------------------------------------ public API

    def write_camera(self, name: str, info: CameraInfo, t_ns: int) -> None:
        """Calibration of camera ``name`` on ``/camera/<name>/calibration`` and its extrinsics
        (``info.pose``, camera → world, OpenCV camera frame) as ``world`` → ``name`` on
        ``/tf``. Call again to move the camera; the intrinsics must stay the same."""
        check_camera_name(name)
        if not isinstance(info, CameraInfo):
            raise TypeError(f"info must be a CameraInfo, got {type(info).__name__}")
        if info.name != name:
            raise ValueError(f"write_camera({name!r}, ...) got a CameraInfo named {info.name!r}")
        if self._spec_cameras and name not in self._spec_cameras:
            raise ValueError(f"camera {name!r} is not in the scene's cameras "
                             f"{sorted(self._spec_cameras)}")
        if name in self._objects or name in self._object_names:
            raise ValueError(f"camera {name!r} has the name of a scene object; "
                             "frame ids must differ")
        check_poses(info.pose, f"camera {name!r}", WRITE_QUAT_TOL)
        old = self._cameras.get(name)
        if old is not None and not old.same_intrinsics(info):
            raise ValueError(f"camera {name!r}: intrinsics changed (was {old.width}x{old.height} "
                             f"K={old.K.tolist()}); a recording keeps one calibration per camera")
        t = self._check_time(TF_TOPIC, t_ns)
        self._check_time(camera_topic(name, "calibration"), t)
        self._cameras[name] = info
        self._write(camera_topic(name, "calibration"), encode_calibration(info, t), t)
        self._write(TF_TOPIC, encode_transforms(t, [name], info.pose.reshape(1, 7), WORLD_FRAME), t)

    def write_poses(self, t_ns: int, names, poses) -> None:
        """One pose sample on ``/tf``: ``world`` → ``names[j]`` for each row of ``poses``
        (n, 7) (tx, ty, tz m, qx, qy, qz, qw; unit quaternions, stored exactly)."""
        names = list(names)
        for n in names:
            check_object_name(n)
        if len(set(names)) != len(names):
            raise ValueError(f"object names repeat: {names}")
        p = check_poses(poses, "write_poses", WRITE_QUAT_TOL)
        if p.shape != (len(names), 7):
            raise ValueError(f"write_poses: {len(names)} names need poses of shape "
                             f"({len(names)}, 7), got {p.shape}")
        unknown = [n for n in names if self._objects and n not in self._objects]
        if unknown:
            raise ValueError(f"objects {unknown} are not in the scene (objects: "
                             f"{sorted(self._objects)})")
        clash = [n for n in names if n in self._cameras or n in self._spec_cameras]
        if clash:
            raise ValueError(f"objects {clash} have the name of a camera; frame ids must differ")
        t = self._check_time(TF_TOPIC, t_ns)
        self._object_names.update(names)
        self._write(TF_TOPIC, encode_transforms(t, names, p, WORLD_FRAME), t)

    def write_mask(self, camera: str, t_ns: int, mask) -> None:
        """Binary liquid mask (H, W) bool (True = liquid) of a camera written before, as
        mono8 (255 = liquid) on ``/camera/<camera>/mask``."""
        info = self._camera(camera)
        m = as_numpy(mask)
        if m.dtype != np.bool_:
            if not np.issubdtype(m.dtype, np.integer) or not np.isin(m, (0, 1)).all():
                raise ValueError(f"mask for {camera!r} must be a bool array (or 0/1 integers), "
                                 f"got dtype {m.dtype}")
            m = m.astype(bool)
        if m.shape != (info.height, info.width):
            raise ValueError(f"mask for {camera!r} has shape {m.shape}, but the camera is "
                             f"calibrated {info.width}x{info.height} (expected "
                             f"({info.height}, {info.width}))")
        topic = camera_topic(camera, "mask")
        t = self._check_time(topic, t_ns)
        self._write(topic, encode_mask(camera, t, m), t)

    def write_image(self, camera: str, t_ns: int, rgb, format: str = "jpeg") -> None:
        """RGB frame (H, W, 3) uint8 of a camera written before, compressed as "jpeg"
        (quality 95) or "png", on ``/camera/<camera>/image``."""
        info = self._camera(camera)
        if format not in ("jpeg", "png"):
            raise ValueError(f"format must be 'jpeg' or 'png', got {format!r}")
        img = as_numpy(rgb)
        if img.dtype != np.uint8 or img.shape != (info.height, info.width, 3):
            raise ValueError(f"image for {camera!r} must be uint8 of shape "
                             f"({info.height}, {info.width}, 3), got {img.dtype} {img.shape}")
        topic = camera_topic(camera, "image")
        t = self._check_time(topic, t_ns)
        self._write(topic, encode_image(camera, t, img, format), t)

    def close(self) -> None:
        """Write the scene if nothing else was, then the MCAP summary and footer."""
        if self._file.closed:
            return
        try:
            if self._start is None:
                self._start = 0
                self._write_scene()
            self._mcap.finish()
        finally:
            self._file.close()

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ helpers

    def _camera(self, camera: str) -> CameraInfo:
        if camera not in self._cameras:
            raise ValueError(f"camera {camera!r} has no calibration yet; call write_camera first "
                             f"(cameras written: {sorted(self._cameras)})")
        return self._cameras[camera]

    def _check_time(self, topic: str, t_ns) -> int:
        if self._file.closed:
            raise ValueError(f"recording {self.path} is already closed")
        t = _stamp(t_ns)
        if self._start is not None and t < self._start:
            raise ValueError(f"{topic}: t_ns={t} is before the recording's start {self._start} "
                             "(the stamp of /scene: start_ns, or the first stamp written)")
        last = self._last.get(topic)
        if last is not None and t < last:
            raise ValueError(f"{topic}: timestamps must not go backwards: t_ns={t} after {last}")
        return t

    def _write_scene(self) -> None:
        if self._spec is not None:
            self._write(SCENE_TOPIC, self._spec, self._start)

    def _write(self, topic: str, msg, t: int) -> None:
        if self._start is None:
            self._start = t
            self._write_scene()
        if topic not in self._channels:
            name = msg.DESCRIPTOR.full_name
            if name not in self._schemas:
                self._schemas[name] = self._mcap.register_schema(
                    name=name, encoding=SchemaEncoding.Protobuf, data=_descriptor_set(type(msg)))
            self._channels[topic] = self._mcap.register_channel(
                topic=topic, message_encoding=MessageEncoding.Protobuf,
                schema_id=self._schemas[name])
        self._seq[topic] = self._seq.get(topic, -1) + 1
        self._last[topic] = t
        self._mcap.add_message(channel_id=self._channels[topic], log_time=t, publish_time=t,
                               sequence=self._seq[topic],
                               data=msg.SerializeToString(deterministic=True))
