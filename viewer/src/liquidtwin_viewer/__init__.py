"""liquidtwin's web viewer: live sessions over Zenoh, or MCAP playback, in a viser page."""

from .buffers import Series, SessionBuffer, SessionSnapshot
from .colormap import auto_vmax, legend_image, pose_to_viser, ramp, speed_colors
from .decode import (
    CameraIntrinsics,
    MeshData,
    Particles,
    StreamError,
    decode_camera,
    decode_meshes,
    decode_metrics,
    decode_overlay,
    decode_particles,
    decode_poses,
    decode_volumes,
)
from .pointclouds import (
    PointCloudSeries,
    RecordingError,
    decode_point_cloud,
    load_point_clouds,
    read_cloud,
)
from .subscribe import FeedConfig, LiveFeed, open_zenoh

__all__ = [
    "CameraIntrinsics",
    "FeedConfig",
    "LiveFeed",
    "MeshData",
    "Particles",
    "PointCloudSeries",
    "RecordingError",
    "Series",
    "SessionBuffer",
    "SessionSnapshot",
    "StreamError",
    "auto_vmax",
    "decode_camera",
    "decode_meshes",
    "decode_metrics",
    "decode_overlay",
    "decode_particles",
    "decode_point_cloud",
    "decode_poses",
    "decode_volumes",
    "legend_image",
    "load_point_clouds",
    "open_zenoh",
    "pose_to_viser",
    "ramp",
    "read_cloud",
    "speed_colors",
]
