"""Connection to a liquidtwin server over Zenoh: :class:`Client` and :class:`ServerError`.

>>> with Client(connect="tcp/127.0.0.1:7447") as client:
...     s = client.create_session(scene_spec, session_id="robot-1")
...     s.publish_poses({"cup": (0, 0, 0, 0, 0, 0, 1)})
...     for out in s.outputs(timeout=1.0): ...

The client opens a Zenoh peer with multicast scouting off, connected to the given
endpoint(s), and declares its liveliness token ``<prefix>/alive/clients/<client_id>``;
sessions it creates are orphaned by the server when that token disappears
(docs/service.md, "Clients that vanish").
"""

from __future__ import annotations

import itertools
import threading
import time
import uuid
from collections.abc import Sequence

import zenoh
from google.protobuf.message import Message
from liquidtwin_proto import (CreateSessionRequest, Keys, ListSessionsReply, ListSessionsRequest,
                              SceneSpec, SessionSpec, SessionStatus, TrackingMode, error_name,
                              make_header, parse_error, validate_session_id)
from liquidtwin_proto import Error

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
#: Timeout of create_session (the server builds and settles the fill: tens of seconds), s.
CREATE_TIMEOUT_S = 120.0
#: Timeout of the other RPCs, s.
RPC_TIMEOUT_S = 10.0
#: How long an RPC keeps asking when no server answers at all, s.
SERVER_WAIT_S = 5.0
#: Tracking mode names accepted by :func:`tracking_mode` (and ``--tracking``).
TRACKING_MODES = {"open_loop": TrackingMode.OPEN_LOOP,
                  "warp_field": TrackingMode.WARP_FIELD,
                  "map_filter": TrackingMode.MAP_FILTER,
                  "spnets_perception": TrackingMode.SPNETS_PERCEPTION}


class ServerError(RuntimeError):
    """The server refused a request (a Zenoh reply_err carrying an ``Error``).

    Attributes:
        code: the ``Error.Code`` number. code_name: its name, e.g. "UNKNOWN_SESSION".
        message: the server's explanation.
    """

    def __init__(self, code: int, code_name: str, message: str):
        super().__init__(f"{code_name}: {message}")
        self.code, self.code_name, self.message = int(code), code_name, message


def tracking_mode(name: str | int) -> int:
    """``TrackingMode`` value of "open_loop", "warp_field", "map_filter",
    "spnets_perception" (or an enum value, passed through)."""
    if isinstance(name, int):
        if name not in TrackingMode.values():
            raise ValueError(f"unknown tracking mode {name}")
        return name
    key = str(name).lower().replace("-", "_")
    if key not in TRACKING_MODES:
        raise ValueError(f"unknown tracking mode {name!r}; expected one of "
                         f"{', '.join(TRACKING_MODES)}")
    return TRACKING_MODES[key]


class Client:
    """A robot-side connection to a liquidtwin server.

    Args:
        connect: Zenoh endpoint(s) to connect to, e.g. "tcp/127.0.0.1:7447" (the server's
            embedded default) or a router's endpoint.
        prefix: key prefix the server uses (``--prefix``), default "liquidtwin".
        client_id: id of this client's liveliness token (a key chunk); default random.
        server_wait: seconds an RPC keeps retrying while no server answers at all before
            raising TimeoutError.

    Use as a context manager (or call :meth:`close`); closing undeclares the liveliness
    token, so the server orphans this client's sessions after its grace time.
    """

    def __init__(self, connect: str | Sequence[str] = DEFAULT_CONNECT, prefix: str = "liquidtwin",
                 client_id: str | None = None, server_wait: float = SERVER_WAIT_S):
        endpoints = [connect] if isinstance(connect, str) else list(connect)
        if not endpoints or not all(isinstance(e, str) and "/" in e for e in endpoints):
            raise ValueError(f"connect must be Zenoh endpoint(s) like 'tcp/127.0.0.1:7447', "
                             f"got {connect!r}")
        self.keys = Keys(prefix)
        self.endpoints = tuple(endpoints)
        self.client_id = client_id or f"client-{uuid.uuid4().hex[:12]}"
        self.server_wait = float(server_wait)
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"peer"')
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("connect/endpoints", "[" + ", ".join(f'"{e}"' for e in endpoints) + "]")
        self._seq = itertools.count()
        self._lock = threading.Lock()
        try:
            self.zenoh = zenoh.open(cfg)
        except zenoh.ZError as exc:
            raise ValueError(f"cannot open a Zenoh session to {', '.join(endpoints)}: {exc}") \
                from None
        self._token = self.zenoh.liveliness().declare_token(
            self.keys.alive("clients", self.client_id))
        self._closed = False

    # -- sessions -----------------------------------------------------------------------
    def create_session(self, spec: SessionSpec | SceneSpec, session_id: str | None = None,
                       tracking: str | int | None = None, timeout: float = CREATE_TIMEOUT_S):
        """Create a session on the server and return its :class:`SessionHandle`.

        Args:
            spec: a SessionSpec, or a SceneSpec (wrapped in a SessionSpec with no cameras).
            session_id: wanted id (a key chunk); None lets the server pick one.
            tracking: "open_loop", "warp_field", "map_filter" or "spnets_perception";
                None keeps the spec's (unset: the server's default, warp_field).
            timeout: seconds to wait for the server to build and settle the fill.

        Raises:
            ServerError: e.g. ALREADY_EXISTS, BAD_REQUEST, INFEASIBLE.
            TimeoutError: no server answered, or not within ``timeout``.
        """
        from .session import SessionHandle

        if isinstance(spec, SceneSpec):
            spec = SessionSpec(scene=spec)
        if not isinstance(spec, SessionSpec):
            raise TypeError(f"spec must be a SessionSpec or SceneSpec, got {type(spec).__name__}")
        spec = SessionSpec.FromString(spec.SerializeToString())
        if tracking is not None:
            spec.tracking = tracking_mode(tracking)
        if session_id is not None:
            validate_session_id(session_id)
        req = CreateSessionRequest(header=self._header(), session_id=session_id or "",
                                   spec=spec, client_id=self.client_id)
        status = self.call(self.keys.rpc("create_session"), req, SessionStatus, timeout)
        return SessionHandle(self, status.session_id, status)

    def session(self, session_id: str):
        """Handle of an existing session (checked with a status RPC; ServerError
        UNKNOWN_SESSION when the server has none of that id)."""
        from .session import SessionHandle

        validate_session_id(session_id)
        handle = SessionHandle(self, session_id, None)
        try:
            handle.last_status = handle.status()
        except BaseException:
            handle.detach()
            raise
        return handle

    def list_sessions(self, timeout: float = RPC_TIMEOUT_S) -> list[SessionStatus]:
        """Status of every session the server holds."""
        reply = self.call(self.keys.rpc("list_sessions"),
                          ListSessionsRequest(header=self._header()), ListSessionsReply, timeout)
        return list(reply.sessions)

    # -- plumbing ------------------------------------------------------------------------
    def call(self, key: str, request: Message, reply_cls: type[Message],
             timeout: float = RPC_TIMEOUT_S) -> Message:
        """Send ``request`` to the queryable at ``key`` and decode the reply as ``reply_cls``.

        While no server answers at all (no queryable matches), retries for
        ``server_wait`` seconds, then raises TimeoutError; a reply_err raises ServerError.
        """
        if self._closed:
            raise RuntimeError("this liquidtwin Client is closed")
        payload = request.SerializeToString()
        start = time.monotonic()
        deadline = start + float(timeout)
        while True:
            left = deadline - time.monotonic()
            replies = list(self.zenoh.get(key, payload=payload, timeout=max(left, 0.01)))
            replies = [r for r in replies if not _is_zenoh_timeout(r)]
            if replies:
                return _decode_reply(replies, reply_cls, key)
            now = time.monotonic()
            if now >= deadline - 1e-3:
                raise TimeoutError(f"the liquidtwin server did not answer {key} within "
                                   f"{timeout:g} s (endpoint {', '.join(self.endpoints)})")
            if now - start >= min(self.server_wait, timeout):
                raise TimeoutError(
                    f"no liquidtwin server answered on {', '.join(self.endpoints)} within "
                    f"{min(self.server_wait, timeout):g} s (key {key}) — is `liquidtwin serve` "
                    f"running, with the same --prefix ({self.keys.prefix!r})?")
            time.sleep(0.1)

    def _header(self, session_id: str = ""):
        with self._lock:
            return make_header(session_id=session_id, seq=next(self._seq))

    def close(self) -> None:
        """Undeclare the liveliness token and close the Zenoh session (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._token.undeclare()
        finally:
            self.zenoh.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _is_zenoh_timeout(reply) -> bool:
    """Zenoh itself ends a query that timed out with the error "Timeout" (never a valid
    serialized Error: 'T' would be an end-group tag)."""
    err = reply.err
    return err is not None and err.payload.to_bytes() == b"Timeout"


def _decode_reply(replies, reply_cls, key):
    """The first successful reply decoded, else the first error as ServerError."""
    first_err = None
    for r in replies:
        if r.ok is not None:
            msg = reply_cls()
            try:
                msg.ParseFromString(r.ok.payload.to_bytes())
            except Exception as exc:  # protobuf raises DecodeError and friends
                raise ServerError(Error.INTERNAL, "INTERNAL",
                                  f"undecodable {reply_cls.DESCRIPTOR.name} reply from {key}: "
                                  f"{exc}") from None
            return msg
        if first_err is None:
            first_err = parse_error(r.err.payload.to_bytes())
    raise ServerError(first_err.code, error_name(first_err.code), first_err.message)
