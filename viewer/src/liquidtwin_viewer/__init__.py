"""liquidtwin's web viewer: draws particle clouds in a viser page."""

from .pointclouds import PointCloudSeries, RecordingError, decode_point_cloud, load_point_clouds

__all__ = ["PointCloudSeries", "RecordingError", "decode_point_cloud", "load_point_clouds"]
