"""Raw-Zenoh helpers of the service tests: a ``liquidtwin serve`` subprocess, a bare Zenoh
peer that speaks the wire by hand (RPCs, inputs with Header attachments, output capture),
small scene specs and Foxglove input encoders written independently of the client library.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import zenoh
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from liquidtwin_proto import liquidtwin_pb2 as pb

BIN = Path(sys.executable).parent
READY_S = 60.0
V = pb.PROTOCOL_VERSION_CURRENT
OUT_TYPES = {"particles": PointCloud, "volumes": pb.Volumes, "metrics": pb.Metrics, "overlay": RawImage,
             "control": pb.Control}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServeProc:
    """``liquidtwin serve`` on a free port of 127.0.0.1; ``ready_s`` = start-to-ready time."""

    def __init__(self, state_dir: Path, *extra: str, log: Path | None = None, connect: str | None = None):
        self.state_dir = Path(state_dir)
        self.endpoint = connect or f"tcp/127.0.0.1:{free_port()}"
        self.log = log or self.state_dir.parent / f"serve-{self.endpoint.rsplit(':', 1)[1]}.log"
        where = ["--connect", connect] if connect else ["--listen", self.endpoint]
        cmd = [str(BIN / "liquidtwin"), "serve", *where, "--state-dir", str(self.state_dir), "--threads", "1", *extra]
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
        self._err = open(self.log, "w")
        t0 = time.monotonic()
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self._err, text=True, env=env,
                                     start_new_session=True)
        self.ready_line = None
        done = threading.Event()

        def read():
            for line in self.proc.stdout:
                if "ready on" in line and self.ready_line is None:
                    self.ready_line = line.strip()
                    done.set()
            done.set()

        threading.Thread(target=read, daemon=True).start()
        done.wait(READY_S)
        self.ready_s = time.monotonic() - t0
        if self.ready_line is None:
            self.kill()
            raise RuntimeError(f"liquidtwin serve not ready within {READY_S} s:\n{self.stderr()[-3000:]}")

    def stderr(self) -> str:
        self._err.flush()
        return self.log.read_text()

    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill(self) -> None:
        """SIGKILL (kill -9): nothing gets flushed or closed by the server."""
        if self.alive():
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> int:
        """SIGTERM and wait (SIGKILL after 20 s); the exit code."""
        if self.alive():
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.kill()
        self._err.close()
        return self.proc.returncode


def header(session: str = "", seq: int = 0, stamp_ns: int | None = None, version: int = V) -> pb.Header:
    return pb.Header(session_id=session, seq=seq, stamp_ns=time.time_ns() if stamp_ns is None else stamp_ns,
                     version=version)


class Peer:
    """A bare Zenoh peer connected to the server; collects the outputs of watched sessions."""

    def __init__(self, endpoint: str, prefix: str = "liquidtwin"):
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"peer"')
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("connect/endpoints", f'["{endpoint}"]')
        self.prefix = prefix
        self.z = zenoh.open(cfg)
        self.outputs: dict[str, list] = defaultdict(list)   # session -> [(stream, Header, message)]
        self.cv = threading.Condition()
        self._subs, self._tokens, self._seq = [], {}, defaultdict(int)

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        for t in self._tokens.values():
            t.undeclare()
        self.z.close()

    # -- rpc
    def query(self, key: str, payload: bytes, timeout: float = 10.0):
        """("ok", bytes) or ("err", Error) of the first reply; ("none", None) without any."""
        for r in self.z.get(f"{self.prefix}/{key}", payload=payload, timeout=timeout):
            if r.ok is not None:
                return "ok", r.ok.payload.to_bytes()
            raw = r.err.payload.to_bytes()
            if raw == b"Timeout":
                return "none", None
            return "err", pb.Error.FromString(raw)
        return "none", None

    def call(self, key: str, request, reply_cls, timeout: float = 10.0):
        kind, body = self.query(key, request.SerializeToString(), timeout)
        if kind != "ok":
            raise AssertionError(f"{key}: {kind} {body}")
        return reply_cls.FromString(body)

    def error(self, key: str, payload: bytes, timeout: float = 10.0) -> pb.Error:
        kind, body = self.query(key, payload, timeout)
        assert kind == "err", (key, kind, body)
        return body

    def create(self, sid: str, spec: pb.SessionSpec, client_id: str = "", timeout: float = 60.0) -> pb.SessionStatus:
        req = pb.CreateSessionRequest(header=header(), session_id=sid, spec=spec, client_id=client_id)
        return self.call("rpc/create_session", req, pb.SessionStatus, timeout)

    def session_rpc(self, sid: str, method: str, request=None, timeout: float = 10.0):
        request = request or pb.SessionRequest(header=header(sid))
        reply = pb.SceneMeshes if method == "meshes" else pb.SessionStatus
        return self.call(f"{sid}/rpc/{method}", request, reply, timeout)

    def list_sessions(self) -> pb.ListSessionsReply:
        return self.call("rpc/list_sessions", pb.ListSessionsRequest(header=header()), pb.ListSessionsReply)

    def token(self, client_id: str) -> None:
        self._tokens[client_id] = self.z.liveliness().declare_token(f"{self.prefix}/alive/clients/{client_id}")

    def drop_token(self, client_id: str) -> None:
        self._tokens.pop(client_id).undeclare()

    # -- streams
    def put(self, sid: str, stream: str, payload: bytes, attachment: bytes | None) -> None:
        key = f"{self.prefix}/{sid}/in/{stream}"
        if attachment is None:
            self.z.put(key, payload)
        else:
            self.z.put(key, payload, attachment=attachment)

    def send(self, sid: str, stream: str, msg, stamp_ns: int) -> int:
        """Publish a well-formed input with a proper Header attachment; returns its seq."""
        seq = self._seq[(sid, stream)]
        self._seq[(sid, stream)] += 1
        self.put(sid, stream, msg.SerializeToString(), header(sid, seq, stamp_ns).SerializeToString())
        return seq

    def watch(self, sid: str) -> None:
        def on(smp):
            stream = str(smp.key_expr).rsplit("/", 1)[1]
            h = pb.Header.FromString(smp.attachment.to_bytes())
            msg = OUT_TYPES[stream].FromString(smp.payload.to_bytes())
            with self.cv:
                self.outputs[sid].append((stream, h, msg))
                self.cv.notify_all()
        self._subs.append(self.z.declare_subscriber(f"{self.prefix}/{sid}/out/*", on))
        # Zenoh drops a put that no known subscriber wants: let the declaration reach the
        # server before the first frame (there is no acknowledgement to wait for)
        time.sleep(0.3)

    def wait_output(self, sid: str, stream: str, stamp_ns: int, timeout: float = 10.0):
        """The ``stream`` output of ``sid`` answering the frame at ``stamp_ns``."""
        deadline = time.monotonic() + timeout
        with self.cv:
            while True:
                for s, h, m in self.outputs[sid]:
                    if s == stream and h.stamp_ns == stamp_ns:
                        return m
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no {stream} of {sid} for stamp {stamp_ns} within {timeout} s")
                self.cv.wait(left)

    def of(self, sid: str, stream: str) -> list:
        with self.cv:
            return [(h, m) for s, h, m in self.outputs[sid] if s == stream]


def wait_until(pred, timeout: float, every: float = 0.05):
    deadline = time.monotonic() + timeout
    while True:
        got = pred()
        if got:
            return got
        if time.monotonic() > deadline:
            raise TimeoutError(f"condition not met within {timeout} s")
        time.sleep(every)


# ---------------------------------------------------------------------------- scenes and inputs
def cup_spec(fraction: float = 0.1, h: float = 0.02, cameras=("cam0",), tracking=pb.OPEN_LOOP) -> pb.SessionSpec:
    """One catalogue cup with a small fill, coarse settings: settles in well under a second."""
    spec = pb.SessionSpec(tracking=tracking)
    o = spec.scene.objects.add(name="cup", model="cup", container=True)
    o.initial_pose.extend([0, 0, 0, 0, 0, 0, 1])
    spec.scene.fills.add(container="cup", fraction=fraction)
    spec.scene.simulation.h, spec.scene.simulation.dt, spec.scene.simulation.iterations = h, 1 / 60, 2
    spec.scene.cameras.extend(cameras)
    return spec


def pour_spec() -> pb.SessionSpec:
    """A filled cup ("src") beside a bowl with a little liquid ("dst")."""
    spec = pb.SessionSpec(tracking=pb.OPEN_LOOP)
    for name, model, x in (("src", "cup", 0.0), ("dst", "bowl", 0.15)):
        o = spec.scene.objects.add(name=name, model=model, container=True)
        o.initial_pose.extend([x, 0, 0, 0, 0, 0, 1])
    spec.scene.fills.add(container="src", fraction=0.3)
    spec.scene.fills.add(container="dst", fraction=0.05)
    spec.scene.simulation.h, spec.scene.simulation.dt, spec.scene.simulation.iterations = 0.02, 1 / 60, 2
    return spec


def stamp_msg(msg, stamp_ns: int):
    msg.timestamp.seconds, msg.timestamp.nanos = divmod(int(stamp_ns), 1_000_000_000)
    return msg


def poses_msg(poses: dict, stamp_ns: int = 0) -> FrameTransforms:
    msg = FrameTransforms()
    for name, p in poses.items():
        tf = msg.transforms.add(parent_frame_id="world", child_frame_id=name)
        stamp_msg(tf, stamp_ns)
        tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in p[:3])
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = (float(v) for v in p[3:])
    return msg


W, H = 160, 120
K = np.array([[150.0, 0, 80], [0, 150.0, 60], [0, 0, 1]])
#: cam0 1 m above the cup, looking straight down (OpenCV frame: z forward = world −y).
CAM_POSE = np.array([0, 0.45, 0, 0.7071067811865476, 0, 0, 0.7071067811865476])


def camera_msg(name: str = "cam0", width: int = W, height: int = H, k=K) -> CameraCalibration:
    return CameraCalibration(frame_id=name, width=width, height=height, distortion_model="plumb_bob", D=[0.0] * 5,
                             K=np.asarray(k, float).ravel().tolist())


def mask_msg(mask: np.ndarray, camera: str = "cam0", encoding: str = "mono8") -> RawImage:
    m = np.where(mask, 255, 0).astype(np.uint8)
    return RawImage(frame_id=camera, width=m.shape[1], height=m.shape[0], encoding=encoding, step=m.shape[1],
                    data=m.tobytes())


def cloud_arrays(cloud: PointCloud) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) positions and (N,) speeds of a particles PointCloud (fields checked)."""
    assert [(f.name, f.offset, f.type) for f in cloud.fields] == [("x", 0, 7), ("y", 4, 7), ("z", 8, 7),
                                                                    ("speed", 12, 7)]
    assert cloud.point_stride == 16 and cloud.frame_id == "world"
    a = np.frombuffer(cloud.data, "<f4").reshape(-1, 4)
    return a[:, :3], a[:, 3]
