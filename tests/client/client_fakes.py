"""A fake liquidtwin server (raw Zenoh queryables and publishers) for the client tests
(the ``fake_server`` fixture is in conftest.py).

It speaks docs/service.md's wire behaviour just enough: RPCs answer SessionStatus /
ListSessionsReply / SceneMeshes or a reply_err Error; every poses sample (a frame) is
answered with particles, volumes and metrics whose values follow simple rules the tests
know independently:

- particles: ``n_particles`` points, point i at (i * 0.01, first transform's ty, -i * 0.01)
  m with speed i m/s, packed by hand with ``struct`` (x, y, z, speed float32, stride 16);
- volumes: container "source" = header.seq of the poses sample, "target" = 1.0 ml;
- metrics: iou 0.5 when a mask arrived since the previous frame, else NaN;
  input_seq = the poses header seq; rejected = ``rejected`` (a settable counter).
"""

from __future__ import annotations

import math
import socket
import struct
import threading
import time

import zenoh
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from liquidtwin_proto import (CreateSessionRequest, Error, Keys, ListSessionsReply,
                              ListSessionsRequest, Metrics, ObjectMesh, SceneMeshes,
                              SessionRequest, SessionStatus, SetTaskRequest, Volumes,
                              decode_attachment, encode_attachment, error_bytes, make_header,
                              pack_array, parse_request)

import numpy as np


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def zenoh_config(listen: str | None = None, connect: str | None = None) -> zenoh.Config:
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if listen:
        cfg.insert_json5("listen/endpoints", f'["{listen}"]')
    if connect:
        cfg.insert_json5("connect/endpoints", f'["{connect}"]')
    return cfg


def particle_cloud(n: int, ty: float) -> PointCloud:
    """The fake's particles, packed independently of the client's decoder."""
    data = b"".join(struct.pack("<4f", i * 0.01, ty, -i * 0.01, float(i)) for i in range(n))
    fields = [PackedElementField(name=k, offset=4 * j, type=PackedElementField.FLOAT32)
              for j, k in enumerate(("x", "y", "z", "speed"))]
    return PointCloud(frame_id="world", point_stride=16, fields=fields, data=data)


class FakeServer:
    """See the module docstring. Attributes the tests read:

    endpoint: where it listens. inputs: [(stream, Header, payload bytes, monotonic s)].
    requests: [(method, session or None, request message)]. sessions: {id: SessionStatus}.
    answered: number of frames answered. skip_stamps: frame stamps left unanswered.
    answer_delay_s: frames are answered that late, from a timer thread.
    close_after: after answering this many frames the session is closed (state "closed").
    create_delay_s: how long create_session takes (replied from another thread).
    """

    def __init__(self, prefix: str = "liquidtwin", n_particles: int = 5):
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.keys = Keys(prefix)
        self.n_particles = n_particles
        self.inputs: list = []
        self.requests: list = []
        self.sessions: dict[str, SessionStatus] = {}
        self.answered = 0
        self.skip_stamps: set[int] = set()
        self.create_delay_s = 0.0
        self.answer_delay_s = 0.0
        self.close_after: int | None = None
        self.answer_times: dict[int, float] = {}  # frame stamp -> monotonic s answered
        self.rejected = 0
        self._mask_pending: dict[str, bool] = {}
        self._out_seq = 0
        self._lock = threading.Lock()
        self.zenoh = zenoh.open(zenoh_config(listen=self.endpoint))
        k = self.keys
        self._decl = [
            self.zenoh.liveliness().declare_token(k.alive("servers", "fake")),
            self.zenoh.declare_queryable(k.rpc("create_session"), self._create),
            self.zenoh.declare_queryable(k.rpc("list_sessions"), self._list),
            self.zenoh.declare_queryable(k.rpc("*", "*"), self._session_rpc),
            self.zenoh.declare_subscriber(k.stream_in("*", "*"), self._input),
        ]

    # -- RPCs --------------------------------------------------------------------------
    def _create(self, query):
        req = parse_request(CreateSessionRequest, query.payload.to_bytes())
        self.requests.append(("create_session", None, req))
        sid = req.session_id or f"auto-{len(self.sessions)}"
        if sid in self.sessions and self.sessions[sid].state != "closed":
            query.reply_err(error_bytes(Error.ALREADY_EXISTS, f"session {sid!r} already exists"))
            return
        status = SessionStatus(header=make_header(sid), session_id=sid, state="running",
                               spec=req.spec, server_id="fake")
        self.sessions[sid] = status
        if self.create_delay_s:
            def later(q=query):
                time.sleep(self.create_delay_s)
                q.reply(q.key_expr, status.SerializeToString())
                q.drop()
            threading.Thread(target=later, daemon=True).start()
        else:
            query.reply(query.key_expr, status.SerializeToString())

    def _list(self, query):
        req = parse_request(ListSessionsRequest, query.payload.to_bytes())
        self.requests.append(("list_sessions", None, req))
        reply = ListSessionsReply(header=make_header(), server_id="fake",
                                  sessions=list(self.sessions.values()))
        query.reply(query.key_expr, reply.SerializeToString())

    def _session_rpc(self, query):
        parsed = self.keys.parse(str(query.key_expr))
        sid, method = parsed.session, parsed.name
        cls = SetTaskRequest if method == "set_task" else SessionRequest
        req = parse_request(cls, query.payload.to_bytes(), session_id=sid)
        self.requests.append((method, sid, req))
        status = self.sessions.get(sid)
        if status is None:
            query.reply_err(error_bytes(Error.UNKNOWN_SESSION, f"no session {sid!r} here"))
            return
        if method == "close":
            status.state = "closed"
        elif method == "set_task":
            status.task.CopyFrom(req.task)
        elif method == "meshes":
            verts = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], np.float32)
            faces = np.array([[0, 1, 2]], np.uint32)
            mesh = ObjectMesh(name="cup", vertices=pack_array(verts), faces=pack_array(faces),
                              container=True)
            reply = SceneMeshes(header=make_header(sid), objects=[mesh])
            query.reply(query.key_expr, reply.SerializeToString())
            return
        elif method not in ("status", "reset"):
            query.reply_err(error_bytes(Error.BAD_REQUEST, f"unknown method {method!r}"))
            return
        status.frames_done = self.answered
        query.reply(query.key_expr, status.SerializeToString())

    # -- streams -----------------------------------------------------------------------
    def _input(self, sample):
        parsed = self.keys.parse(str(sample.key_expr))
        att = sample.attachment
        header = decode_attachment(att.to_bytes() if att is not None else None, parsed.session)
        payload = sample.payload.to_bytes()
        with self._lock:
            self.inputs.append((parsed.name, header, payload, time.monotonic()))
            if parsed.name == "mask":
                self._mask_pending[parsed.session] = True
            if parsed.name != "poses" or header.stamp_ns in self.skip_stamps:
                return
            if self.close_after is not None and self.answered >= self.close_after:
                self.sessions[parsed.session].state = "closed"
                return
            had_mask = self._mask_pending.pop(parsed.session, False)
        args = (parsed.session, header, FrameTransforms.FromString(payload), had_mask)
        if self.answer_delay_s:
            threading.Timer(self.answer_delay_s, self._answer, args).start()
        else:
            self._answer(*args)

    def _answer(self, sid, header, tfs, had_mask):
        with self._lock:
            self._answer_locked(sid, header, tfs, had_mask)

    def _answer_locked(self, sid, header, tfs, had_mask):
        ty = tfs.transforms[0].translation.y
        vols = Volumes(header=make_header(sid, header.seq, header.stamp_ns))
        vols.containers.add(name="source", ml=float(header.seq))
        vols.containers.add(name="target", ml=1.0)
        metrics = Metrics(header=make_header(sid, header.seq, header.stamp_ns),
                          input_seq=header.seq, iou=0.5 if had_mask else math.nan,
                          frames_done=self.answered + 1, rejected=self.rejected)
        # Stamped before the outputs go out: the client may see all three, finish and close
        # before this thread runs again (a CI run once found the last stamp missing).
        self.answer_times[header.stamp_ns] = time.monotonic()
        for stream, msg in (("particles", particle_cloud(self.n_particles, ty)),
                            ("volumes", vols), ("metrics", metrics)):
            att = encode_attachment(make_header(sid, self._out_seq, header.stamp_ns))
            self._out_seq += 1
            self.zenoh.put(self.keys.stream_out(sid, stream), msg.SerializeToString(),
                           attachment=att, congestion_control=zenoh.CongestionControl.BLOCK)
        self.answered += 1

    def publish_raw(self, sid, stream, payload, attachment):
        """Publish an arbitrary output sample (for malformed-output tests)."""
        self.zenoh.put(self.keys.stream_out(sid, stream), payload, attachment=attachment)

    def inputs_of(self, stream):
        return [(h, p) for s, h, p, _ in self.inputs if s == stream]

    def close(self):
        for d in reversed(self._decl):
            d.undeclare()
        self.zenoh.close()


def wait_until(cond, timeout=5.0):
    """Poll ``cond()`` until true or ``timeout`` s; returns its last value."""
    deadline = time.monotonic() + timeout
    while not (ok := cond()) and time.monotonic() < deadline:
        time.sleep(0.02)
    return ok
