"""Topic layout of liquidtwin recordings, and how topics of any MCAP are recognised.

A recording is "measured data": what a tracker, calibrated cameras and a liquid
segmentation saw. Ground truth never goes in it (it lives in a ``.truth.json`` sidecar).

Layout written by :class:`~liquidtwin.recordings.RecordingWriter` (protobuf encoding,
schemas embedded, chunks compressed with zstd, chunk / data-section / summary CRCs; every
message's log time = publish time = its own stamp, in ns):

- ``/scene`` — ``liquidtwin.v1.SceneSpec``, once, at the recording's first stamp.
- ``/tf`` — ``foxglove.FrameTransforms``: per pose sample one transform per object (parent
  ``world``, child = object name, pose object → world); camera extrinsics as transforms
  ``world`` → camera name (camera → world; camera frame OpenCV: x right, y down, z forward).
- ``/camera/<name>/calibration`` — ``foxglove.CameraCalibration``: frame_id = camera name,
  width, height, K, D (5, ``plumb_bob``), R = I, P = [K | 0].
- ``/camera/<name>/mask`` — ``foxglove.RawImage`` mono8 binary liquid mask, 255 = liquid.
- ``/camera/<name>/image`` — ``foxglove.CompressedImage``, optional RGB frames, jpeg or png.

Reading any conforming MCAP (ours or a user's), topics are found by **schema**, not name:
``foxglove.FrameTransforms`` / ``FrameTransform`` / ``PosesInFrame`` → poses;
``foxglove.CameraCalibration`` → cameras; ``foxglove.RawImage`` / ``CompressedImage`` →
masks when the topic name contains ``mask``, RGB images otherwise; ``liquidtwin.v1.SceneSpec``
→ the scene. A ``PosesInFrame`` holds the scene's objects in order (so it needs a scene).
Transforms must all hang off one frame (``world`` if present). Images belong to the camera named by their ``frame_id`` (or, when that is
empty, by the topic component before the last, e.g. ``/cam0/mask`` → ``cam0``). A
``topics={topic: kind}`` mapping overrides the discovery for the topics it names; kinds are
:data:`KINDS` (``"ignore"`` drops a topic).
"""

from __future__ import annotations

from collections.abc import Mapping

from .base import check_camera_name

SCENE_TOPIC = "/scene"
TF_TOPIC = "/tf"
WORLD_FRAME = "world"
PROTOBUF = "protobuf"

SCENE_SCHEMA = "liquidtwin.v1.SceneSpec"
POSE_SCHEMAS = ("foxglove.FrameTransforms", "foxglove.FrameTransform", "foxglove.PosesInFrame")
CALIBRATION_SCHEMAS = ("foxglove.CameraCalibration",)
IMAGE_SCHEMAS = ("foxglove.RawImage", "foxglove.CompressedImage")

#: What a topic can hold, and the schemas each kind accepts.
KINDS: dict[str, tuple[str, ...]] = {
    "scene": (SCENE_SCHEMA,),
    "poses": POSE_SCHEMAS,
    "calibration": CALIBRATION_SCHEMAS,
    "mask": IMAGE_SCHEMAS,
    "image": IMAGE_SCHEMAS,
    "ignore": (),
}


def camera_topic(camera: str, what: str) -> str:
    """``/camera/<camera>/<what>`` for what in calibration, mask, image."""
    if what not in ("calibration", "mask", "image"):
        raise ValueError(f"no camera topic for {what!r}; expected calibration, mask or image")
    return f"/camera/{check_camera_name(camera)}/{what}"


def classify(topic: str, schema_name: str) -> str:
    """The kind of a topic from its schema name (and, for images, its name); ``"ignore"``
    for schemas liquidtwin does not read."""
    if schema_name == SCENE_SCHEMA:
        return "scene"
    if schema_name in POSE_SCHEMAS:
        return "poses"
    if schema_name in CALIBRATION_SCHEMAS:
        return "calibration"
    if schema_name in IMAGE_SCHEMAS:
        return "mask" if "mask" in topic.lower() else "image"
    return "ignore"


def check_topics(topics: Mapping[str, str] | None) -> dict[str, str]:
    """Validate a ``topics=`` override: {topic: kind}."""
    if topics is None:
        return {}
    if not isinstance(topics, Mapping):
        raise TypeError(f"topics must be a mapping {{topic: kind}}, got {type(topics).__name__}")
    out = {}
    for topic, kind in topics.items():
        if kind not in KINDS:
            raise ValueError(f"topics[{topic!r}] = {kind!r}: kind must be one of {sorted(KINDS)}")
        out[str(topic)] = kind
    return out


def camera_of_image(topic: str, frame_id: str) -> str:
    """Camera an image or mask belongs to: its frame id, else the topic's second-last part."""
    if frame_id:
        return frame_id
    parts = [p for p in topic.split("/") if p]
    return parts[-2] if len(parts) >= 2 else ""
