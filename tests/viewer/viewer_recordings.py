"""Writes small MCAP files of foxglove.PointCloud messages for the viewer tests."""

import numpy as np
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap_protobuf.writer import Writer

T0 = 1_700_000_000_000_000_000  # ns


def xyz_cloud(points: np.ndarray) -> PointCloud:
    """A PointCloud of (N, 3) points packed as float32 x, y, z (stride 12 bytes)."""
    fields = [PackedElementField(name=n, offset=4 * i, type=PackedElementField.FLOAT32)
              for i, n in enumerate("xyz")]
    data = np.ascontiguousarray(points, dtype="<f4").tobytes()
    return PointCloud(frame_id="world", point_stride=12, fields=fields, data=data)


def write_clouds(path, frames, *, topic="/particles", dt_ns=100_000_000, extra=()):
    """Write each (N_i, 3) array of ``frames`` as one PointCloud on ``topic``, dt_ns apart;
    ``extra`` is a sequence of (topic, protobuf message) written after them."""
    with open(path, "wb") as f:
        writer = Writer(f)
        for i, points in enumerate(frames):
            t = T0 + i * dt_ns
            writer.write_message(topic, xyz_cloud(points), log_time=t, publish_time=t)
        for other_topic, message in extra:
            writer.write_message(other_topic, message, log_time=T0, publish_time=T0)
        writer.finish()
    return path


def three_frames() -> list[np.ndarray]:
    """Three clouds of 4, 5 and 6 points with distinct, exactly representable values."""
    return [np.arange(3 * n, dtype=np.float32).reshape(n, 3) / 8 + i
            for i, n in enumerate((4, 5, 6))]
