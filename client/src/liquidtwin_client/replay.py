"""A recording (MCAP) as the input samples a robot would have sent, in stamp order.

Topics are recognised by schema (any conforming MCAP, not only liquidtwin's):
``liquidtwin.v1.SceneSpec`` → the scene; ``foxglove.FrameTransforms`` / ``FrameTransform``
/ ``PosesInFrame`` → poses; ``foxglove.CameraCalibration`` → camera; ``foxglove.RawImage``
/ ``CompressedImage`` → mask when the topic name contains "mask", else image. Other
topics are ignored. A sample's stamp is its message timestamp, or the MCAP log time when
that is zero. All pose messages of one stamp become one FrameTransforms (one frame), sent
after that stamp's camera, mask and image samples (docs/service.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from liquidtwin_proto import CameraSetup, SceneSpec, SessionSpec
from mcap.reader import make_reader

from .connection import tracking_mode
from .messages import WORLD, stamp_of, timestamp
from .recording import RecordingError, _check_file

_ORDER = {"camera": 0, "mask": 1, "image": 2, "poses": 3}
_SCHEMAS = {
    "liquidtwin.v1.SceneSpec": SceneSpec, "foxglove.FrameTransforms": FrameTransforms,
    "foxglove.FrameTransform": FrameTransform, "foxglove.PosesInFrame": PosesInFrame,
    "foxglove.CameraCalibration": CameraCalibration, "foxglove.RawImage": RawImage,
    "foxglove.CompressedImage": CompressedImage,
}


@dataclass(frozen=True)
class InputSample:
    """One input sample ready to publish.

    Attributes:
        stamp_ns: time its content refers to, ns since the Unix epoch.
        stream: "camera", "mask", "image" or "poses".
        payload: the serialized Foxglove message.
        name: camera name (camera/mask/image), "" for poses.
    """

    stamp_ns: int
    stream: str
    payload: bytes
    name: str = ""


@dataclass(frozen=True)
class Frame:
    """Everything recorded at one stamp, in sending order (camera, mask, image, poses)."""

    stamp_ns: int
    samples: tuple[InputSample, ...]

    @property
    def has_poses(self) -> bool:
        """True if this stamp carries a poses sample (then it is a frame for the server)."""
        return any(s.stream == "poses" for s in self.samples)


@dataclass(frozen=True)
class Replay:
    """A recording ready to stream.

    Attributes:
        path: the file read. scene: its SceneSpec (header cleared).
        cameras: one CameraSetup per calibrated camera (first calibration, first pose).
        stamps: every stamp's samples, in stamp order.
    """

    path: str
    scene: SceneSpec
    cameras: tuple[CameraSetup, ...]
    stamps: tuple[Frame, ...]

    @property
    def frames(self) -> tuple[Frame, ...]:
        """The stamps that carry poses (the frames the server answers)."""
        return tuple(f for f in self.stamps if f.has_poses)

    def session_spec(self, tracking: str | int | None = None) -> SessionSpec:
        """SessionSpec of the recorded scene and cameras (tracking None: server default)."""
        spec = SessionSpec(scene=self.scene, cameras=self.cameras)
        if tracking is not None:
            spec.tracking = tracking_mode(tracking)
        return spec


def load_replay(path: str | Path) -> Replay:
    """Read ``path`` into a :class:`Replay`.

    Raises:
        RecordingError: not a complete MCAP, no ``/scene`` (SceneSpec), a pose parented to
            a frame other than ``world``, or a camera image with no camera name.
    """
    path = Path(path)
    _check_file(path)
    scene, samples = None, []
    try:
        with path.open("rb") as stream:
            for schema, channel, message in make_reader(stream).iter_messages(log_time_order=True):
                cls = _SCHEMAS.get(schema.name if schema else "")
                if cls is None or channel.message_encoding != "protobuf":
                    continue
                msg = cls.FromString(message.data)
                if cls is SceneSpec:
                    scene = scene or msg
                    continue
                samples.extend(_samples(channel.topic, msg, message.log_time, scene))
    except RecordingError:
        raise
    except Exception as exc:  # the mcap / protobuf libraries raise many kinds
        raise RecordingError(f"{path}: cannot read ({type(exc).__name__}: {exc})") from exc
    if scene is None:
        raise RecordingError(f"{path}: no liquidtwin.v1.SceneSpec (/scene) in the recording; "
                             "a session needs the scene it shows")
    scene = SceneSpec.FromString(scene.SerializeToString())
    scene.ClearField("header")
    stamps = _group(samples)
    return Replay(str(path), scene, _cameras(samples), stamps)


def _samples(topic: str, msg, log_time: int, scene) -> list[InputSample]:
    if isinstance(msg, (FrameTransforms, FrameTransform, PosesInFrame)):
        return [_poses(topic, msg, log_time, scene)]
    stamp = stamp_of(msg.timestamp) or log_time
    name = msg.frame_id or _camera_from_topic(topic)
    if not name:
        raise RecordingError(f"{topic}: message has no frame_id and the topic names no camera")
    if msg.frame_id != name:
        msg.frame_id = name
    if isinstance(msg, CameraCalibration):
        kind = "camera"
    else:
        kind = "mask" if "mask" in topic.lower() else "image"
    return [InputSample(stamp, kind, msg.SerializeToString(), name)]


def _poses(topic, msg, log_time, scene) -> InputSample:
    """Poses sample as a FrameTransforms (validated parent, stamp of the first transform)."""
    if isinstance(msg, PosesInFrame):
        if scene is None or len(msg.poses) != len(scene.objects):
            raise RecordingError(f"{topic}: a PosesInFrame needs a /scene before it with as "
                                 "many objects as it has poses")
        out, stamp = FrameTransforms(), stamp_of(msg.timestamp) or log_time
        for obj, pose in zip(scene.objects, msg.poses):
            tf = out.transforms.add(parent_frame_id=msg.frame_id or WORLD,
                                    child_frame_id=obj.name)
            tf.timestamp.CopyFrom(timestamp(stamp))
            tf.translation.CopyFrom(pose.position)
            tf.rotation.CopyFrom(pose.orientation)
        msg = out
    elif isinstance(msg, FrameTransform):
        msg = FrameTransforms(transforms=[msg])
    if not msg.transforms:
        raise RecordingError(f"{topic}: empty FrameTransforms")
    for tf in msg.transforms:
        if tf.parent_frame_id not in (WORLD, ""):
            raise RecordingError(f"{topic}: transform {tf.parent_frame_id!r} → "
                                 f"{tf.child_frame_id!r}; liquidtwin needs poses in "
                                 f"{WORLD!r} (parent_frame_id = {WORLD!r})")
        tf.parent_frame_id = WORLD
    stamp = stamp_of(msg.transforms[0].timestamp) or log_time
    return InputSample(stamp, "poses", msg.SerializeToString())


def _group(samples: list[InputSample]) -> tuple[Frame, ...]:
    """Per stamp: the samples in sending order, all poses merged into one (later wins)."""
    by_stamp: dict[int, list[InputSample]] = {}
    for s in samples:
        by_stamp.setdefault(s.stamp_ns, []).append(s)
    frames = []
    for stamp in sorted(by_stamp):
        group = by_stamp[stamp]
        poses = [s for s in group if s.stream == "poses"]
        rest = sorted((s for s in group if s.stream != "poses"), key=lambda s: _ORDER[s.stream])
        if poses:
            merged: dict[str, object] = {}
            for s in poses:
                for tf in FrameTransforms.FromString(s.payload).transforms:
                    merged[tf.child_frame_id] = tf
            out = FrameTransforms(transforms=list(merged.values()))
            rest.append(InputSample(stamp, "poses", out.SerializeToString()))
        frames.append(Frame(stamp, tuple(rest)))
    return tuple(frames)


def _cameras(samples: list[InputSample]) -> tuple[CameraSetup, ...]:
    """CameraSetup per camera: its first calibration and its first pose, if any."""
    setups: dict[str, CameraSetup] = {}
    for s in samples:
        if s.stream == "camera" and s.name not in setups:
            cal = CameraCalibration.FromString(s.payload)
            setups[s.name] = CameraSetup(name=s.name, width=cal.width, height=cal.height,
                                         k=list(cal.K), d=(list(cal.D) + [0.0] * 5)[:5])
    for s in samples:
        if s.stream != "poses":
            continue
        for tf in FrameTransforms.FromString(s.payload).transforms:
            cam = setups.get(tf.child_frame_id)
            if cam is not None and not cam.pose:
                t, q = tf.translation, tf.rotation
                cam.pose.extend([t.x, t.y, t.z, q.x, q.y, q.z, q.w])
    return tuple(setups.values())


def _camera_from_topic(topic: str) -> str:
    parts = [p for p in topic.split("/") if p]
    return parts[-2] if len(parts) >= 2 else ""
