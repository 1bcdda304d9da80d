"""One checked pass over a recording in file order: which topic holds what, the scene, every
transform and calibration, and (optionally) the decoded masks and images.

All problems become RecordingError naming the file, the topic and, where it applies, the
time of the message.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame

from ._codec import (CLASSES, decode_calibration, decode_mask, decode_poses_in_frame,
                     decode_rgb, decode_transforms, stamp_ns)
from ._interp import interpolate_poses
from ._scan import RawMessage, check_file, iter_raw
from .base import READ_QUAT_TOL, CameraInfo, RecordingError, check_poses, fmt_time
from .topics import KINDS, PROTOBUF, WORLD_FRAME, camera_of_image, check_topics, classify

_IDENTITY = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


class Collection:
    """What a recording holds. Build with :meth:`run`; then ``object_names``, ``root``,
    ``objects`` / ``camera_poses`` ({name: (times (K,) int64 ns, poses (K, 7))}), ``cameras``
    ({name: CameraInfo at its first pose}), ``masks`` / ``images`` ({camera: [(t, array)]})."""

    def __init__(self, path, topics=None, *, images: bool = True, keep_masks: bool = True,
                 keep_images: bool = True):
        self.path = Path(path)
        self.override = check_topics(topics)
        self.want_images, self.keep_masks, self.keep_images = images, keep_masks, keep_images
        self.spec = None
        self.schemas: dict[str, str] = {}      # every topic → schema name
        self.kinds: dict[str, str] = {}        # every topic → kind
        self.transforms = defaultdict(list)    # child → [(t, parent, pose, topic)]
        self.poses_in_frame = []               # [(topic, t, frame, poses)]
        self.calibrations: dict[str, tuple] = {}  # camera → (CameraInfo at identity, topic)
        self.masks = defaultdict(list)         # camera → [(t, (H, W) bool | None, topic, shape)]
        self.images = defaultdict(list)        # camera → [(t, rgb)]
        self.t_min = self.t_max = None
        self._last: dict[tuple, int] = {}

    # ------------------------------------------------------------------ pass over the file

    def run(self) -> "Collection":
        check_file(self.path)
        for raw in iter_raw(self.path, log_time_order=False):
            self._take(raw)
        missing = sorted(set(self.override) - set(self.schemas))
        if missing:
            raise RecordingError(f"{self.path}: topics {missing} given in topics= are not in the "
                                 f"file (topics: {sorted(self.schemas)})")
        self._finish()
        return self

    def error(self, topic: str, problem: str, t: int | None = None) -> RecordingError:
        at = "" if t is None else f" at t={fmt_time(t)}"
        return RecordingError(f"{self.path}: topic {topic!r}{at}: {problem}")

    def kind(self, raw: RawMessage) -> str:
        """Kind of a message's topic (checked schema and encodings), or "ignore"."""
        kind = self.kinds.get(raw.topic)
        if kind is not None:
            return kind
        self.schemas[raw.topic] = raw.schema_name
        kind = self.override.get(raw.topic) or classify(raw.topic, raw.schema_name)
        if kind == "image" and not self.want_images:
            kind = "ignore"
        if kind != "ignore":
            if raw.schema_name not in KINDS[kind]:
                raise self.error(raw.topic, f"schema {raw.schema_name!r} cannot hold {kind}; "
                                 f"expected one of {list(KINDS[kind])}")
            if (raw.schema_encoding, raw.message_encoding) != (PROTOBUF, PROTOBUF):
                raise self.error(raw.topic, f"{raw.schema_name} in schema encoding "
                                 f"{raw.schema_encoding!r} / message encoding "
                                 f"{raw.message_encoding!r} is not supported (only protobuf); "
                                 f"pass topics={{{raw.topic!r}: 'ignore'}} to skip it")
        self.kinds[raw.topic] = kind
        return kind

    def decode(self, raw: RawMessage):
        try:
            return CLASSES[raw.schema_name].FromString(raw.data)
        except Exception as e:
            raise self.error(raw.topic, f"message #{raw.index} is not a valid {raw.schema_name} "
                             f"({type(e).__name__}: {e})") from e

    def _check_order(self, topic: str, key: str, t: int, what: str) -> None:
        last = self._last.get((topic, key))
        if last is not None and t < last:
            raise self.error(topic, f"timestamps go backwards for {what}: {fmt_time(t)} "
                             f"after {fmt_time(last)}")
        self._last[(topic, key)] = t
        self.t_min = t if self.t_min is None else min(self.t_min, t)
        self.t_max = t if self.t_max is None else max(self.t_max, t)

    def image_camera(self, raw: RawMessage, msg) -> str:
        camera = camera_of_image(raw.topic, msg.frame_id)
        if not camera:
            raise self.error(raw.topic, "image has no frame_id and the topic names no camera")
        return camera

    def _take(self, raw: RawMessage) -> None:
        kind = self.kind(raw)
        if kind == "ignore":
            return
        msg = self.decode(raw)
        if kind == "scene":
            self._check_order(raw.topic, "", raw.log_time, "the scene")
            if self.spec is None:
                self.spec = msg
        elif kind == "poses" and isinstance(msg, PosesInFrame):
            t, frame, poses = self.wrap(raw, decode_poses_in_frame, msg, raw.log_time)
            self._check_order(raw.topic, "", t, "PosesInFrame")
            self.poses_in_frame.append((raw.topic, t, frame, poses))
        elif kind == "poses":
            for t, parent, child, pose in self.wrap(raw, decode_transforms, msg, raw.log_time):
                self._check_order(raw.topic, child, t, f"frame {child!r}")
                self.transforms[child].append((t, parent, pose, raw.topic))
        elif kind == "calibration":
            camera = self.image_camera(raw, msg)
            t = self.wrap(raw, stamp_ns, msg, raw.log_time)
            self._check_order(raw.topic, camera, t, f"camera {camera!r}")
            msg.frame_id = camera
            info = self.wrap(raw, decode_calibration, msg, _IDENTITY, t=t)
            old = self.calibrations.get(camera)
            if old is not None and not old[0].same_intrinsics(info):
                raise self.error(raw.topic, f"calibration of camera {camera!r} changes "
                                 "(size, K or D); one calibration per camera is supported", t)
            self.calibrations.setdefault(camera, (info, raw.topic))
        else:
            camera = self.image_camera(raw, msg)
            t = self.wrap(raw, stamp_ns, msg, raw.log_time)
            self._check_order(raw.topic, camera, t, f"camera {camera!r}")
            if kind == "mask":
                mask = self.wrap(raw, decode_mask, msg, t=t)
                self.masks[camera].append((t, mask if self.keep_masks else None, raw.topic,
                                           mask.shape))
            elif self.keep_images:
                self.images[camera].append((t, self.wrap(raw, decode_rgb, msg, t=t)))

    def wrap(self, raw: RawMessage, fn, *args, t: int | None = None):
        try:
            return fn(*args)
        except ValueError as e:
            raise self.error(raw.topic, str(e), t) from e

    # ------------------------------------------------------------------ checks across topics

    def _finish(self) -> None:
        pose_topics = [tp for tp, k in self.kinds.items() if k == "poses"]
        if not pose_topics:
            listed = ", ".join(f"{tp} ({s or 'no schema'})"
                               for tp, s in sorted(self.schemas.items()))
            raise RecordingError(f"{self.path}: no pose topic: expected a channel with schema "
                                 f"foxglove.FrameTransforms, FrameTransform or PosesInFrame "
                                 f"(topics in the file: {listed or 'none'})")
        for camera, items in self.masks.items():
            if camera not in self.calibrations:
                raise self.error(items[0][2], f"masks of camera {camera!r} have no "
                                 f"foxglove.CameraCalibration with frame_id {camera!r} "
                                 f"(calibrated cameras: {sorted(self.calibrations)})")
            info = self.calibrations[camera][0]
            for t, _, topic, shape in items:
                if shape != (info.height, info.width):
                    raise self.error(topic, f"mask of camera {camera!r} is {shape[1]}x{shape[0]} "
                                     f"px but its calibration is {info.width}x{info.height} px", t)
        cams = set(self.calibrations)
        spec_objects = [o.name for o in self.spec.objects] if self.spec is not None else []
        self.root = self._root(spec_objects, cams)
        if spec_objects:
            self.object_names = spec_objects
        else:
            self.object_names = [c for c, items in self.transforms.items()
                                 if c not in cams and items[0][1] == self.root]
        self.objects = {n: self._series(n, self.transforms.get(n, [])) for n in self.object_names}
        self._add_poses_in_frame()
        never = [n for n, (times, _) in self.objects.items() if len(times) == 0]
        if never or not self.object_names:
            seen = sorted(c for c in self.transforms if c not in cams)
            raise RecordingError(f"{self.path}: the transforms on {sorted(pose_topics)} never "
                                 f"mention scene object(s) {never or '(none found)'}; child "
                                 f"frames seen: {seen}")
        self.camera_poses, self.cameras = {}, {}
        for camera, (info, topic) in self.calibrations.items():
            times, poses = self._series(camera, self.transforms.get(camera, []))
            if len(times) == 0:
                raise self.error(topic, f"camera {camera!r} has a calibration but no transform "
                                 f"{self.root!r} → {camera!r} on any pose topic")
            self.camera_poses[camera] = (times, poses)
            self.cameras[camera] = info.with_pose(poses[0])

    def _root(self, spec_objects: list[str], cams: set[str]) -> str:
        needed = set(spec_objects) | cams
        parents = {p for c, items in self.transforms.items() for _, p, _, _ in items
                   if not spec_objects or c in needed}
        parents |= {frame for _, _, frame, _ in self.poses_in_frame}
        if WORLD_FRAME in parents or not parents:
            return WORLD_FRAME
        if len(parents) == 1:
            return parents.pop()
        raise RecordingError(f"{self.path}: cannot tell the world frame: object and camera "
                             f"transforms have parents {sorted(parents)}; give all of them "
                             f"relative to one frame (chained transforms are not supported)")

    def _series(self, name: str, items: list) -> tuple[np.ndarray, np.ndarray]:
        """(times (K,) int64, poses (K, 7)) of one frame; a repeated stamp keeps the last."""
        for t, parent, _, topic in items:
            if parent != self.root:
                raise self.error(topic, f"frame {name!r} is given relative to {parent!r}, not "
                                 f"{self.root!r}; chained transforms are not supported", t)
        items = sorted(items, key=lambda it: it[0])
        by_time = {t: (pose, topic) for t, _, pose, topic in items}
        times = np.fromiter(by_time, dtype=np.int64, count=len(by_time))
        poses = np.array([p for p, _ in by_time.values()], dtype=np.float64).reshape(-1, 7)
        for t, (pose, topic) in by_time.items():
            try:
                check_poses(pose, f"pose of {name!r}", READ_QUAT_TOL)
            except ValueError as e:
                raise self.error(topic, str(e), t) from e
        return times, poses

    def _add_poses_in_frame(self) -> None:
        if not self.poses_in_frame:
            return
        topic = self.poses_in_frame[0][0]
        if self.spec is None or not self.spec.objects:
            raise self.error(topic, "PosesInFrame poses are matched to the scene's objects in "
                             "order, but the recording has no /scene with objects")
        rows = defaultdict(list)
        for topic, t, frame, poses in self.poses_in_frame:
            if len(poses) != len(self.object_names):
                raise self.error(topic, f"PosesInFrame holds {len(poses)} poses but the scene "
                                 f"has {len(self.object_names)} objects {self.object_names}", t)
            for name, pose in zip(self.object_names, poses):
                rows[name].append((t, frame, pose, topic))
        for name in self.object_names:
            extra = [(t, self.root, pose, tp) for t, _, pose, tp in self.transforms.get(name, [])]
            self.objects[name] = self._series(name, extra + rows[name])

    # ------------------------------------------------------------------ lookups

    def camera_at(self, camera: str, t: int) -> CameraInfo:
        """The camera with its pose at time t (ns), interpolated between its transforms."""
        times, poses = self.camera_poses[camera]
        return self.cameras[camera].with_pose(interpolate_poses(times, poses, [t])[0])
