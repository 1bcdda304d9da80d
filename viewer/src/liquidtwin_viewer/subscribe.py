"""The Zenoh side of the live viewer: subscribe to every session's streams, decode each
sample into its session's :class:`SessionBuffer`, and poll the server's RPCs.

Callbacks only decode and store (O(sample size), no waiting); RPCs (``list_sessions``,
``<s>/rpc/meshes``) run on the feed's own poll thread.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

from liquidtwin_proto import (
    Keys,
    ListSessionsReply,
    ListSessionsRequest,
    SessionRequest,
    WireError,
    decode_attachment,
    error_name,
    make_header,
    parse,
    parse_error,
)

from .buffers import SessionBuffer, SessionSnapshot
from .decode import (
    StreamError,
    decode_camera,
    decode_meshes,
    decode_metrics,
    decode_overlay,
    decode_particles,
    decode_poses,
    decode_volumes,
)

log = logging.getLogger("liquidtwin_viewer")

#: Streams the viewer draws: (direction, name).
STREAMS = (("out", "particles"), ("out", "overlay"), ("out", "metrics"), ("out", "volumes"),
           ("in", "poses"), ("in", "camera"))


@dataclass(frozen=True)
class FeedConfig:
    """Settings of a LiveFeed.

    Attributes:
        prefix: Zenoh key prefix of the service.
        window_s: length of plotted history, s.
        poll_s: period of the ``list_sessions`` / ``meshes`` polls, s.
        rpc_timeout_s: how long one RPC may take, s.
    """

    prefix: str = "liquidtwin"
    window_s: float = 30.0
    poll_s: float = 3.0
    rpc_timeout_s: float = 2.0


def open_zenoh(connect: str | None = None, listen: str | None = None):
    """A Zenoh peer session with multicast scouting off, connected to / listening on the
    given endpoints (e.g. ``tcp/127.0.0.1:7447``)."""
    import zenoh

    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("scouting/multicast/enabled", "false")
    if connect:
        cfg.insert_json5("connect/endpoints", f'["{connect}"]')
    if listen:
        cfg.insert_json5("listen/endpoints", f'["{listen}"]')
    return zenoh.open(cfg)


class LiveFeed:
    """Buffers of every session seen on the wire under one prefix.

    Args:
        session: an open Zenoh session (or None to drive :meth:`handle_sample` by hand).
        config: prefix, history window, poll period.
    """

    def __init__(self, session=None, config: FeedConfig = FeedConfig()):
        self.config = config
        self.keys = Keys(config.prefix)
        self._zenoh = session
        self._lock = threading.Lock()
        self._buffers: dict[str, SessionBuffer] = {}
        self._listed: tuple[str, ...] = ()
        self._statuses: dict = {}
        self._warned: set[str] = set()
        self._subs = []
        self._stop = threading.Event()
        self._wake = threading.Event()  # a new session appeared: poll now for its meshes
        self._poller: threading.Thread | None = None

    def start(self) -> "LiveFeed":
        """Declare the subscribers and start the poll thread."""
        if self._zenoh is None:
            raise RuntimeError("LiveFeed.start needs a Zenoh session")
        for direction, stream in STREAMS:
            key = f"{self.config.prefix}/*/{direction}/{stream}"
            self._subs.append(self._zenoh.declare_subscriber(key, self._on_sample))
        self._poller = threading.Thread(target=self._poll, name="liquidtwin-poll", daemon=True)
        self._poller.start()
        return self

    def close(self) -> None:
        """Stop polling and undeclare the subscribers (the Zenoh session stays open)."""
        self._stop.set()
        self._wake.set()
        if self._poller is not None:
            self._poller.join(timeout=self.config.rpc_timeout_s + 1.0)
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # session already closed
                pass
        self._subs.clear()

    def sessions(self) -> list[str]:
        """Ids of the listed sessions and of those seen on the streams, sorted."""
        with self._lock:
            return sorted(set(self._listed) | set(self._buffers))

    def status(self, session: str):
        """The newest SessionStatus from ``list_sessions`` for ``session``, or None."""
        with self._lock:
            return self._statuses.get(session)

    def buffer(self, session: str) -> SessionBuffer:
        """The buffer of ``session`` (created on first use)."""
        with self._lock:
            buf = self._buffers.get(session)
            if buf is None:
                buf = self._buffers[session] = SessionBuffer(session, self.config.window_s)
                self._wake.set()
            return buf

    def snapshot(self, session: str) -> SessionSnapshot:
        """The current state of ``session``."""
        return self.buffer(session).snapshot()

    def _on_sample(self, sample) -> None:
        att = sample.attachment
        try:
            self.handle_sample(str(sample.key_expr), sample.payload.to_bytes(),
                               att.to_bytes() if att is not None else None)
        except Exception as exc:  # never let a callback raise into Zenoh
            log.exception("liquidtwin-viewer: sample on %s: %s", sample.key_expr, exc)

    def handle_sample(self, key: str, payload: bytes, attachment: bytes | None) -> None:
        """Decode one stream sample into its session's buffer.

        A sample whose key is not ours is ignored; one that does not decode is counted in
        the buffer's ``rejected`` and its cause logged once.
        """
        try:
            parsed = self.keys.parse(key)
        except ValueError:
            return
        if parsed.session is None or (parsed.kind, parsed.name) not in STREAMS:
            return
        buf = self.buffer(parsed.session)
        try:
            stamp = decode_attachment(attachment, parsed.session).stamp_ns
            self._store(buf, parsed.name, payload, stamp)
        except (StreamError, WireError) as exc:
            reason = f"{parsed.kind}/{parsed.name}: {exc}"
            buf.reject(reason)
            if reason not in self._warned:
                self._warned.add(reason)
                log.warning("liquidtwin-viewer: session %s: %s", parsed.session, reason)

    @staticmethod
    def _store(buf: SessionBuffer, stream: str, payload: bytes, stamp: int) -> None:
        if stream == "particles":
            buf.add_particles(stamp, decode_particles(payload))
        elif stream == "overlay":
            buf.add_overlay(*decode_overlay(payload))
        elif stream == "metrics":
            buf.add_metrics(stamp, decode_metrics(payload))
        elif stream == "volumes":
            buf.add_volumes(stamp, decode_volumes(payload))
        elif stream == "poses":
            buf.add_poses(decode_poses(payload))
        elif stream == "camera":
            buf.add_camera(decode_camera(payload))

    def refresh(self) -> None:
        """One poll: ``list_sessions``, then ``meshes`` of every known session lacking them."""
        request = ListSessionsRequest(header=make_header()).SerializeToString()
        for payload in self._query(self.keys.rpc("list_sessions"), request):
            try:
                reply = parse(ListSessionsReply, payload)
            except WireError as exc:
                log.warning("liquidtwin-viewer: list_sessions reply: %s", exc)
                continue
            with self._lock:
                self._statuses = {s.session_id: s for s in reply.sessions}
                self._listed = tuple(s.session_id for s in reply.sessions if s.state != "closed")
        for sid in self.sessions():
            buf = self.buffer(sid)
            if buf.has_meshes():
                continue
            request = SessionRequest(header=make_header(sid)).SerializeToString()
            for payload in self._query(self.keys.rpc("meshes", sid), request):
                try:
                    buf.set_meshes(decode_meshes(payload))
                except StreamError as exc:
                    buf.reject(f"rpc/meshes: {exc}")
                break

    def _query(self, key: str, payload: bytes) -> list[bytes]:
        """Payloads of the successful replies to a Zenoh get; errors are logged once."""
        if self._zenoh is None:
            return []
        out = []
        try:
            replies = self._zenoh.get(key, payload=payload, timeout=self.config.rpc_timeout_s)
            for reply in replies:
                if reply.ok is not None:
                    out.append(reply.ok.payload.to_bytes())
                else:
                    err = parse_error(reply.err.payload.to_bytes())
                    reason = f"{key}: {error_name(err.code)}: {err.message}"
                    if reason not in self._warned:
                        self._warned.add(reason)
                        log.warning("liquidtwin-viewer: %s", reason)
        except Exception as exc:  # closed session, timeouts surface as no replies
            log.debug("liquidtwin-viewer: query %s failed: %s", key, exc)
        return out

    def _poll(self) -> None:
        while not self._stop.is_set():
            started = time.monotonic()
            self._wake.clear()
            self.refresh()
            self._wake.wait(max(0.0, self.config.poll_s - (time.monotonic() - started)))
