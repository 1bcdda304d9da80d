"""MCAP recordings of simulation output, readable by Foxglove and ``liquidtwin-viewer``.

Topics (protobuf encoding, schemas embedded):

- ``/particles``: ``foxglove.PointCloud`` in frame ``world`` with an identity pose,
  ``point_stride`` 12 and float32 fields x, y, z at offsets 0, 4, 8 (little-endian);
- ``/objects``: ``foxglove.FrameTransforms``, one transform ``world`` → object name per
  object, from its 7-D pose (tx, ty, tz, qx, qy, qz, qw);
- ``/volumes``: ``liquidtwin.v1.Volumes``, liquid per container in ml.

Log and publish times are ``start_ns`` plus the simulation time in nanoseconds.

>>> with Recorder("out/demo.mcap") as rec:
...     rec.write(t, x, poses=poses, names=("cup", "bowl"), volumes={"cup": 120.0})
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp
from liquidtwin_proto import PROTOCOL_VERSION, liquidtwin_pb2
from mcap_protobuf.writer import Writer

PARTICLES_TOPIC = "/particles"
OBJECTS_TOPIC = "/objects"
VOLUMES_TOPIC = "/volumes"
WORLD_FRAME = "world"


def _numpy(a) -> np.ndarray:
    if hasattr(a, "detach"):
        a = a.detach().cpu().numpy()
    return np.asarray(a)


def _timestamp(ns: int) -> Timestamp:
    return Timestamp(seconds=ns // 1_000_000_000, nanos=ns % 1_000_000_000)


def point_cloud(x, stamp_ns: int = 0, frame_id: str = WORLD_FRAME) -> PointCloud:
    """A ``foxglove.PointCloud`` of (N, 3) positions (m) as packed little-endian float32 xyz."""
    x = _numpy(x)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {x.shape}")
    fields = [PackedElementField(name=n, offset=4 * i, type=PackedElementField.FLOAT32)
              for i, n in enumerate("xyz")]
    return PointCloud(
        timestamp=_timestamp(stamp_ns), frame_id=frame_id,
        pose=Pose(position=Vector3(x=0.0, y=0.0, z=0.0),
                  orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
        point_stride=12, fields=fields, data=np.ascontiguousarray(x, dtype="<f4").tobytes())


def frame_transforms(poses, names, stamp_ns: int = 0, parent: str = WORLD_FRAME) -> FrameTransforms:
    """``foxglove.FrameTransforms``: a ``parent`` → ``names[j]`` transform per pose row (M, 7)."""
    poses = _numpy(poses).astype(np.float64).reshape(-1, 7)
    if len(names) != poses.shape[0]:
        raise ValueError(f"{poses.shape[0]} poses but {len(names)} names")
    ts = _timestamp(stamp_ns)
    out = FrameTransforms()
    for name, p in zip(names, poses):
        q = p[3:] / np.linalg.norm(p[3:])
        out.transforms.append(FrameTransform(
            timestamp=ts, parent_frame_id=parent, child_frame_id=str(name),
            translation=Vector3(x=p[0], y=p[1], z=p[2]),
            rotation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])))
    return out


def volumes_message(volumes: dict[str, float], stamp_ns: int = 0, seq: int = 0,
                    session_id: str = "") -> liquidtwin_pb2.Volumes:
    """``liquidtwin.v1.Volumes`` from a {container name: ml} dict."""
    msg = liquidtwin_pb2.Volumes(header=liquidtwin_pb2.Header(
        session_id=session_id, seq=seq, stamp_ns=stamp_ns, version=PROTOCOL_VERSION))
    for name, ml in volumes.items():
        msg.containers.append(liquidtwin_pb2.ContainerVolume(name=str(name), ml=float(ml)))
    return msg


class Recorder:
    """Writes simulation frames to an MCAP file (a context manager; call :meth:`close`).

    Args:
      path: output file; parent directories are created.
      start_ns: time of sim time 0, ns (default 0: log times are sim time).
      session_id: goes into the ``Volumes`` header.
    """

    def __init__(self, path: str | Path, *, start_ns: int = 0, session_id: str = "demo"):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.start_ns = int(start_ns)
        self.session_id = session_id
        self.frames = 0
        self._file = open(self.path, "wb")
        self._writer = Writer(self._file)

    def stamp(self, t: float) -> int:
        """Log time of sim time ``t`` (s), ns."""
        return self.start_ns + int(round(t * 1e9))

    def write(self, t: float, x, *, poses=None, names=(),
              volumes: dict[str, float] | None = None) -> None:
        """Record one frame at sim time ``t`` (s): particles (N, 3), optional object poses
        (M, 7) with their names, optional volumes {name: ml}."""
        ns = self.stamp(t)
        seq = self.frames
        messages = [(PARTICLES_TOPIC, point_cloud(x, ns))]
        if poses is not None and len(names):
            messages.append((OBJECTS_TOPIC, frame_transforms(poses, names, ns)))
        if volumes is not None:
            messages.append((VOLUMES_TOPIC, volumes_message(volumes, ns, seq, self.session_id)))
        for topic, msg in messages:
            self._writer.write_message(topic, msg, log_time=ns, publish_time=ns, sequence=seq)
        self.frames += 1

    def write_state(self, state, names=(), volumes: dict[str, float] | None = None) -> None:
        """Record a :class:`~liquidtwin.sim.FluidState` (particles in id order, its poses)."""
        x, _ = state.by_id()
        self.write(state.t, x, poses=state.poses, names=names, volumes=volumes)

    def close(self) -> None:
        if self._file.closed:
            return
        try:
            self._writer.finish()
        finally:
            self._file.close()

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
