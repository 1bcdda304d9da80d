"""A stand-in for the liquidtwin server on Zenoh, for the live viewer tests: answers
``list_sessions`` and ``<s>/rpc/meshes`` and publishes a session's streams with the schemas
and Header attachments of docs/service.md."""

from __future__ import annotations

import socket

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from liquidtwin_proto import (
    ContainerVolume,
    Keys,
    ListSessionsReply,
    Metrics,
    ObjectMesh,
    SceneMeshes,
    SessionStatus,
    Volumes,
    encode_attachment,
    make_header,
    pack_array,
)

T0 = 1_700_000_000_000_000_000  # ns
OBSERVED, MODEL, BOTH, BACKGROUND = (0, 0, 255), (0, 255, 0), (255, 255, 0), (40, 40, 40)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def particles_msg(points: np.ndarray, speed: np.ndarray) -> PointCloud:
    """PointCloud in frame world, float32 fields x, y, z, speed (stride 16)."""
    fields = [PackedElementField(name=n, offset=4 * i, type=PackedElementField.FLOAT32)
              for i, n in enumerate(("x", "y", "z", "speed"))]
    data = np.concatenate([points, speed[:, None]], axis=1).astype("<f4").tobytes()
    return PointCloud(frame_id="world", point_stride=16, fields=fields, data=data)


def poses_msg(poses: dict) -> FrameTransforms:
    """FrameTransforms of name -> (7,) pose (tx, ty, tz, qx, qy, qz, qw), parent world."""
    msg = FrameTransforms()
    for name, p in poses.items():
        tf = FrameTransform(parent_frame_id="world", child_frame_id=name)
        tf.translation.x, tf.translation.y, tf.translation.z = map(float, p[:3])
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = map(float, p[3:])
        msg.transforms.append(tf)
    return msg


def camera_msg(name: str, width: int, height: int, f: float) -> CameraCalibration:
    k = [f, 0, width / 2, 0, f, height / 2, 0, 0, 1]
    return CameraCalibration(frame_id=name, width=width, height=height,
                             distortion_model="plumb_bob", D=[0.0] * 5, K=k)


def overlay_msg(camera: str, image: np.ndarray, step_pad: int = 0) -> RawImage:
    h, w, _ = image.shape
    rows = np.zeros((h, 3 * w + step_pad), np.uint8)
    rows[:, : 3 * w] = image.reshape(h, 3 * w)
    return RawImage(frame_id=camera, width=w, height=h, encoding="rgb8", step=3 * w + step_pad,
                    data=rows.tobytes())


def overlay_image(width: int = 160, height: int = 120) -> np.ndarray:
    """Three bands (observed, both, model) over the dark background, thesis Fig. 8.10."""
    img = np.empty((height, width, 3), np.uint8)
    img[:] = BACKGROUND
    img[height // 4: 3 * height // 4, width // 8: 3 * width // 8] = OBSERVED
    img[height // 4: 3 * height // 4, 3 * width // 8: 5 * width // 8] = BOTH
    img[height // 4: 3 * height // 4, 5 * width // 8: 7 * width // 8] = MODEL
    return img


def box_mesh(half: tuple[float, float, float], name: str, container: bool) -> ObjectMesh:
    """Axis-aligned box standing on y = 0, half extents (m), as an ObjectMesh."""
    hx, hy, hz = half
    v = np.array([[x, y, z] for x in (-hx, hx) for y in (0.0, 2 * hy) for z in (-hz, hz)],
                 np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], np.uint32)
    return ObjectMesh(name=name, vertices=pack_array(v), faces=pack_array(f), container=container)


def block_of_liquid(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) points in a 0.1 m cube above the origin, (n,) speeds growing with height."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-0.05, 0.0, -0.05], [0.05, 0.1, 0.05], (n, 3)).astype(np.float32)
    return pts, (pts[:, 1] * 10).astype(np.float32)


class FakeService:
    """Plays the liquidtwin server's role on an open Zenoh session.

    Args:
        zenoh_session: open Zenoh session.
        sessions: session ids that ``list_sessions`` reports (state running).
        meshes: session id -> ObjectMesh list answered by ``<s>/rpc/meshes``.
    """

    def __init__(self, zenoh_session, sessions=("demo",), meshes=None, prefix="liquidtwin"):
        self.z, self.keys = zenoh_session, Keys(prefix)
        self.sessions, self.meshes = list(sessions), dict(meshes or {})
        self.seq: dict = {}
        self.queries: list[str] = []
        self._qs = [self.z.declare_queryable(self.keys.rpc("list_sessions"), self._list)]
        for sid in self.meshes:
            self._qs.append(self.z.declare_queryable(self.keys.rpc("meshes", sid),
                                                     self._meshes_of(sid)))

    def _list(self, query) -> None:
        self.queries.append(str(query.key_expr))
        reply = ListSessionsReply(header=make_header(), server_id="fake", sessions=[
            SessionStatus(session_id=s, state="running") for s in self.sessions])
        query.reply(query.key_expr, reply.SerializeToString())

    def _meshes_of(self, sid):
        def answer(query) -> None:
            self.queries.append(str(query.key_expr))
            msg = SceneMeshes(header=make_header(sid), objects=self.meshes[sid])
            query.reply(query.key_expr, msg.SerializeToString())
        return answer

    def publish(self, session: str, direction: str, stream: str, msg, stamp_ns: int) -> None:
        """Put ``msg`` on ``<prefix>/<session>/<direction>/<stream>`` with a Header."""
        key = (self.keys.stream_out if direction == "out" else self.keys.stream_in)(
            session, stream)
        seq = self.seq[key] = self.seq.get(key, -1) + 1
        header = make_header(session, seq, stamp_ns)
        self.z.put(key, msg.SerializeToString(), attachment=encode_attachment(header))

    def frame(self, session: str, i: int, *, n: int = 8000, dt_ns: int = 33_000_000,
              camera: str = "cam0", overlay: bool = True) -> None:
        """Publish one full frame ``i`` of a pour-like session."""
        stamp = T0 + i * dt_ns
        pts, speed = block_of_liquid(n, seed=i)
        self.publish(session, "in", "camera", camera_msg(camera, 160, 120, 150.0), stamp)
        cam_pose = camera_pose_looking_at(np.array([-0.3, 0.25, 0.3]), np.zeros(3))
        self.publish(session, "in", "poses", poses_msg(
            {"cup": np.array([0, 0, 0, 0, 0, 0, 1.0]),
             "target": np.array([0.2, 0, 0, 0, 0, 0, 1.0]), camera: cam_pose}), stamp)
        self.publish(session, "out", "particles", particles_msg(pts, speed), stamp)
        self.publish(session, "out", "volumes", Volumes(containers=[
            ContainerVolume(name="cup", ml=200 - i), ContainerVolume(name="target", ml=i)]),
            stamp)
        self.publish(session, "out", "metrics", Metrics(
            input_seq=i, iou=0.5 + 0.4 * np.sin(i / 5), lag_ms=12.0, particles=n), stamp)
        if overlay:
            self.publish(session, "out", "overlay", overlay_msg(camera, overlay_image()), stamp)

    def close(self) -> None:
        for q in self._qs:
            q.undeclare()


def camera_pose_looking_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(7,) camera → world pose, OpenCV frame (z forward, y down), world y up."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z], axis=1)  # columns: camera axes in world
    w = np.sqrt(max(1e-12, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    q = np.array([(r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w),
                  (r[1, 0] - r[0, 1]) / (4 * w), w])
    return np.concatenate([eye, q / np.linalg.norm(q)])
