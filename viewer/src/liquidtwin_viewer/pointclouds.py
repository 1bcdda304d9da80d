"""Foxglove ``foxglove.PointCloud`` messages from an MCAP recording as NumPy arrays."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap.reader import make_reader

SCHEMA_NAME = PointCloud.DESCRIPTOR.full_name  # "foxglove.PointCloud"

_NUMERIC = {
    PackedElementField.UINT8: "u1",
    PackedElementField.INT8: "i1",
    PackedElementField.UINT16: "<u2",
    PackedElementField.INT16: "<i2",
    PackedElementField.UINT32: "<u4",
    PackedElementField.INT32: "<i4",
    PackedElementField.FLOAT32: "<f4",
    PackedElementField.FLOAT64: "<f8",
}


class RecordingError(Exception):
    """A recording, topic or message the viewer cannot show."""


@dataclass(frozen=True)
class PointCloudSeries:
    """Point clouds of one topic, in log-time order.

    Attributes:
        topic: the MCAP topic read.
        times_ns: (T,) int64 log times, ns since the Unix epoch, non-decreasing.
        frames: T arrays of shape (N_t, 3) float32, points in the cloud's frame_id, m;
            N_t may change from frame to frame.
    """

    topic: str
    times_ns: np.ndarray
    frames: tuple[np.ndarray, ...]

    def __len__(self) -> int:
        return len(self.frames)


def decode_point_cloud(cloud: PointCloud) -> np.ndarray:
    """Positions of a ``foxglove.PointCloud``, moved by its ``pose``.

    Reads the ``x``, ``y``, ``z`` fields (any numeric type; at least two must be present,
    a missing one reads as 0) of each ``point_stride``-byte record of ``data``. Points
    with a non-finite coordinate are dropped.

    Returns:
        (N, 3) float32 positions in ``cloud.frame_id``, m.

    Raises:
        RecordingError: bad stride, field layout or data length.
    """
    points, _ = read_cloud(cloud)
    return points


def read_cloud(cloud: PointCloud, extra: tuple[str, ...] = ()) -> tuple[np.ndarray, dict]:
    """Positions and other per-point fields of a ``foxglove.PointCloud``.

    Args:
        cloud: the message; ``x``, ``y``, ``z`` as in :func:`decode_point_cloud`.
        extra: names of further numeric fields to read (e.g. ``("speed",)``); one the
            cloud lacks reads as NaN.

    Returns:
        points: (N, 3) float32 positions moved by ``cloud.pose``, m; points with a
            non-finite coordinate are dropped.
        fields: name -> (N,) float32 values of each ``extra`` field, same rows as points.

    Raises:
        RecordingError: bad stride, field layout or data length.
    """
    stride = cloud.point_stride
    if stride <= 0:
        raise RecordingError(f"point_stride must be positive, got {stride}")
    if len(cloud.data) % stride:
        raise RecordingError(
            f"data holds {len(cloud.data)} bytes, not a multiple of point_stride {stride}"
        )
    wanted = ("x", "y", "z", *extra)
    fields = {f.name: f for f in cloud.fields if f.name in wanted}
    if sum(name in fields for name in "xyz") < 2:
        raise RecordingError(
            f"point cloud needs at least two of the fields x, y, z; "
            f"has {sorted(n for n in fields if n in 'xyz')}"
        )
    names, formats, offsets = [], [], []
    for name, field in fields.items():
        fmt = _NUMERIC.get(field.type)
        if fmt is None:
            raise RecordingError(f"field {name!r} has unsupported numeric type {field.type}")
        if field.offset + np.dtype(fmt).itemsize > stride:
            raise RecordingError(
                f"field {name!r} at offset {field.offset} overruns stride {stride}"
            )
        names.append(name)
        formats.append(fmt)
        offsets.append(field.offset)
    record = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": stride})
    records = np.frombuffer(cloud.data, dtype=record)
    points = np.zeros((len(records), 3), np.float64)
    for axis, name in enumerate("xyz"):
        if name in fields:
            points[:, axis] = records[name]
    if cloud.HasField("pose"):
        points = points @ _rotation(cloud.pose.orientation).T + _xyz(cloud.pose.position)
    keep = np.isfinite(points).all(axis=1)
    values = {
        name: (records[name][keep].astype(np.float32) if name in fields
               else np.full(int(keep.sum()), np.nan, np.float32))
        for name in extra
    }
    return points[keep].astype(np.float32), values


def load_point_clouds(path: str | Path, topic: str = "/particles") -> PointCloudSeries:
    """Read every ``foxglove.PointCloud`` on ``topic`` of an MCAP file.

    Raises:
        RecordingError: missing or invalid file, missing topic, a topic of another
            schema, no messages, or a malformed point cloud (with its log time).
    """
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    times, frames = [], []
    try:
        with path.open("rb") as stream:
            reader = make_reader(stream)
            summary = reader.get_summary()
            if summary is not None:
                _check_topic(path, topic, summary)
            for schema, channel, message in reader.iter_messages(topics=[topic]):
                encoding = channel.message_encoding
                if schema is None or schema.name != SCHEMA_NAME or encoding != "protobuf":
                    raise RecordingError(
                        f"{path}: topic {topic!r} carries "
                        f"{schema.name if schema else 'schemaless'} "
                        f"{encoding} messages, not protobuf {SCHEMA_NAME}"
                    )
                try:
                    frames.append(decode_point_cloud(PointCloud.FromString(message.data)))
                except RecordingError as exc:
                    raise RecordingError(
                        f"{path}: {topic} message at log time {message.log_time} ns: {exc}"
                    ) from exc
                times.append(message.log_time)
    except RecordingError:
        raise
    except Exception as exc:  # the mcap and protobuf libraries raise many kinds
        raise RecordingError(f"{path}: cannot read MCAP ({type(exc).__name__}: {exc})") from exc
    if not frames:
        raise RecordingError(f"{path}: no messages on topic {topic!r}")
    return PointCloudSeries(topic, np.asarray(times, np.int64), tuple(frames))


def _check_topic(path: Path, topic: str, summary) -> None:
    schemas = summary.schemas
    by_topic = {c.topic: schemas.get(c.schema_id) for c in summary.channels.values()}
    if topic not in by_topic:
        clouds = sorted(t for t, s in by_topic.items() if s is not None and s.name == SCHEMA_NAME)
        hint = f"; {SCHEMA_NAME} topics there: {', '.join(clouds)}" if clouds else (
            f"; it has no {SCHEMA_NAME} topic"
        )
        raise RecordingError(f"{path}: no topic {topic!r}{hint}")


def _xyz(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z], np.float64)


def _rotation(q) -> np.ndarray:
    """(3, 3) rotation matrix of quaternion q (x, y, z, w); a zero quaternion is identity."""
    x, y, z, w = q.x, q.y, q.z, q.w
    n = x * x + y * y + z * z + w * w
    if n == 0.0:
        return np.eye(3)
    s = 2.0 / n
    return np.array(
        [
            [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
        ]
    )
