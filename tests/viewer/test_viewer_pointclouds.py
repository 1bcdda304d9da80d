"""MCAP -> arrays: decoding foxglove.PointCloud and loading a topic."""

import struct

import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField as Field
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from viewer_recordings import T0, three_frames, write_clouds, xyz_cloud

from liquidtwin_viewer import RecordingError, decode_point_cloud, load_point_clouds


def test_load_three_frames(tmp_path):
    frames = three_frames()
    series = load_point_clouds(write_clouds(tmp_path / "r.mcap", frames))
    assert len(series) == 3 and series.topic == "/particles"
    np.testing.assert_array_equal(series.times_ns, [T0, T0 + 10**8, T0 + 2 * 10**8])
    assert series.times_ns.dtype == np.int64
    for got, want in zip(series.frames, frames):
        assert got.dtype == np.float32 and got.shape == want.shape
        np.testing.assert_array_equal(got, want)


def test_load_other_topic_and_ignore_the_rest(tmp_path):
    path = write_clouds(tmp_path / "r.mcap", three_frames()[:2], topic="/truth",
                        extra=[("/camera", CompressedImage(format="png"))])
    assert len(load_point_clouds(path, "/truth")) == 2


def test_decode_applies_pose():
    cloud = xyz_cloud(np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.5]]))
    s = np.sqrt(0.5)  # 90 degrees about +z
    cloud.pose.CopyFrom(Pose())
    cloud.pose.position.x, cloud.pose.position.y, cloud.pose.position.z = 1.0, 2.0, 3.0
    cloud.pose.orientation.z, cloud.pose.orientation.w = s, s
    np.testing.assert_allclose(decode_point_cloud(cloud), [[1, 3, 3], [-1, 2, 3.5]], atol=1e-6)


def test_decode_padded_float64_records_with_missing_z():
    # stride 24: x (f8) at 0, intensity (u4) at 8, y (f8) at 12, 4 bytes padding; no z.
    fields = [Field(name="x", offset=0, type=Field.FLOAT64),
              Field(name="intensity", offset=8, type=Field.UINT32),
              Field(name="y", offset=12, type=Field.FLOAT64)]
    data = struct.pack("<dIdxxxx", 1.5, 7, -2.0) + struct.pack("<dIdxxxx", 3.0, 9, 4.25)
    cloud = PointCloud(point_stride=24, fields=fields, data=data)
    np.testing.assert_array_equal(decode_point_cloud(cloud), [[1.5, -2.0, 0.0], [3.0, 4.25, 0.0]])


def test_decode_drops_non_finite_points():
    cloud = xyz_cloud(np.array([[0, 0, 0], [np.nan, 1, 1], [1, np.inf, 1], [2, 2, 2]]))
    np.testing.assert_array_equal(decode_point_cloud(cloud), [[0, 0, 0], [2, 2, 2]])


def test_decode_empty_cloud():
    assert decode_point_cloud(xyz_cloud(np.zeros((0, 3)))).shape == (0, 3)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda c: setattr(c, "point_stride", 0), "point_stride must be positive"),
        (lambda c: setattr(c, "data", c.data[:-1]), "not a multiple of point_stride"),
        (lambda c: (c.ClearField("fields"), c.fields.add(name="x", type=Field.FLOAT32)),
         "at least two of the fields"),
        (lambda c: setattr(c.fields[2], "offset", 10), "overruns stride"),
        (lambda c: setattr(c.fields[0], "type", Field.UNKNOWN), "unsupported numeric type"),
    ],
    ids=["stride", "length", "fields", "overrun", "type"],
)
def test_decode_rejects_malformed_clouds(change, message):
    cloud = xyz_cloud(np.ones((2, 3)))
    change(cloud)
    with pytest.raises(RecordingError, match=message):
        decode_point_cloud(cloud)


def test_load_errors(tmp_path):
    good = write_clouds(tmp_path / "r.mcap", three_frames(),
                        extra=[("/camera", CompressedImage(format="png"))])
    with pytest.raises(RecordingError, match="no such file"):
        load_point_clouds(tmp_path / "missing.mcap")
    with pytest.raises(RecordingError,
                       match="no topic '/nope'; foxglove.PointCloud topics there: /particles"):
        load_point_clouds(good, "/nope")
    with pytest.raises(RecordingError, match="carries foxglove.CompressedImage protobuf messages"):
        load_point_clouds(good, "/camera")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all" * 3)
    with pytest.raises(RecordingError, match="cannot read MCAP"):
        load_point_clouds(junk)


def test_load_reports_which_message_is_malformed(tmp_path):
    bad = xyz_cloud(np.ones((2, 3)))
    bad.point_stride = 5
    path = write_clouds(tmp_path / "r.mcap", [np.ones((1, 3))], extra=[("/particles", bad)])
    with pytest.raises(RecordingError, match=f"message at log time {T0} ns: .*point_stride 5"):
        load_point_clouds(path)
