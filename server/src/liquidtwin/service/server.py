"""The liquidtwin server: Zenoh RPCs, input streams, liveliness and the served sessions.

:class:`Server` answers the RPCs of docs/service.md on a small thread pool (never on the
Zenoh callback thread; ``create_session``, which settles a fill, on a pool of its own),
routes input samples to their session's checks and inbox, restores the sessions it finds
under the state dir at start, and orphans / closes sessions whose client's liveliness token
vanished. Every failure is a ``reply_err`` carrying an ``Error``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
import uuid
from concurrent.futures import ThreadPoolExecutor

import zenoh
from google.protobuf.descriptor import FieldDescriptor
from liquidtwin_proto import (CreateSessionRequest, DiscrepancyRequest, Error, InferBlockageRequest, InferFillRequest,
                              Keys, ListSessionsReply, ListSessionsRequest, LoadModelRequest,
                              SessionRequest, SetTaskRequest, WireError, error_bytes, make_header, parse_request,
                              validate_id, validate_session_id)

from ..session import EngineError, SessionEngine
from .detector import make_detector
from .checkpoint import read_meta, read_spec, restorable, sessions_root, write_session_files
from .config import ServeConfig, zenoh_config
from .outputs import scene_meshes
from .session import ServedSession

_log = logging.getLogger("liquidtwin.serve")
SESSION_METHODS = ("status", "reset", "close", "set_task", "meshes", "infer_fill", "infer_blockage", "discrepancy",
                   "load_model")
#: Session RPCs that run a long analysis: served by their own pool so status/reset stay quick.
SLOW_METHODS = ("infer_fill", "infer_blockage", "discrepancy")
#: Seconds a session's client token may be unseen at creation/restore before it counts as gone.
TOKEN_SETTLE_S = 2.0
_REJECT_LOG_EVERY_S = 10.0
_FLOATS = (FieldDescriptor.CPPTYPE_DOUBLE, FieldDescriptor.CPPTYPE_FLOAT)


def _non_finite(msg, path: str = "") -> str | None:
    """Dotted path of the first NaN/inf float or double in a protobuf message, else None."""
    for fd, value in msg.ListFields():
        name = f"{path}{fd.name}"
        sub_type = fd.message_type
        if sub_type is not None and sub_type.GetOptions().map_entry:
            vf = sub_type.fields_by_name["value"]
            if vf.message_type is not None:
                subs = [(f"{name}[{k}].", v) for k, v in value.items()]
            else:
                if vf.cpp_type in _FLOATS and not all(math.isfinite(v) for v in value.values()):
                    return name
                continue
        elif sub_type is not None:
            subs = [(f"{name}[{i}].", v) for i, v in enumerate(value)] if fd.is_repeated else [(f"{name}.", value)]
        else:
            if fd.cpp_type in _FLOATS and not all(math.isfinite(v) for v in (value if fd.is_repeated else [value])):
                return name
            continue
        for sub_path, sub in subs:
            bad = _non_finite(sub, sub_path)
            if bad:
                return bad
    return None


class Server:
    """A running liquidtwin server. ``engine_factory(spec, device=...)`` builds a session's
    engine (default :meth:`SessionEngine.create`; tests inject fakes)."""

    def __init__(self, config: ServeConfig, engine_factory=None):
        self.config = config
        self.keys = Keys(config.prefix)
        self.factory = engine_factory or SessionEngine.create
        self.sessions: dict[str, ServedSession] = {}
        self._creating: set[str] = set()
        self._lock = threading.RLock()
        self._alive_clients: set[str] = set()
        self._deadline: dict[str, float] = {}
        self._rejects: dict[tuple, list] = {}
        self.unknown_session_samples = 0
        self._rpc_pool = ThreadPoolExecutor(4, thread_name_prefix="rpc")
        self._create_pool = ThreadPoolExecutor(2, thread_name_prefix="create")
        self._infer_pool = ThreadPoolExecutor(1, thread_name_prefix="infer")
        self._stop = threading.Event()
        self._decls = []
        self.z = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Open Zenoh, restore sessions from the state dir, declare keys and liveliness."""
        sessions_root(self.config.state_dir).mkdir(parents=True, exist_ok=True)
        self.z = zenoh.open(zenoh_config(self.config))
        self._restore()
        k, z = self.keys, self.z
        self._decls = [
            z.liveliness().declare_subscriber(k.alive("clients", "*"), self._on_alive, history=True),
            z.declare_subscriber(k.stream_in("*", "*"), self._on_input),
            z.declare_queryable(k.rpc("*"), self._on_query),
            z.declare_queryable(k.rpc("*", "*"), self._on_query),
            z.liveliness().declare_token(k.alive("servers", self.config.server_id)),
        ]
        self._house = threading.Thread(target=self._housekeeping, name="housekeeping", daemon=True)
        self._house.start()

    def stop(self) -> None:
        """Undeclare everything, checkpoint and close every session's log (not marked closed:
        a restart restores them), close Zenoh."""
        self._stop.set()
        for d in reversed(self._decls):
            try:
                d.undeclare()
            except Exception:  # noqa: BLE001
                pass
        self._rpc_pool.shutdown(wait=True, cancel_futures=True)
        self._create_pool.shutdown(wait=False, cancel_futures=True)
        self._infer_pool.shutdown(wait=False, cancel_futures=True)
        with self._lock:
            sessions = list(self.sessions.values())
            self.sessions.clear()
        for s in sessions:
            s.close(final=False)
        if self.z is not None:
            self.z.close()

    def _restore(self) -> None:
        for sid, d in restorable(self.config.state_dir):
            t0 = time.monotonic()
            try:
                spec, meta = read_spec(d), read_meta(d)
                engine = self.factory(spec, device=spec.device or self.config.device)
                s = ServedSession(sid, engine, spec, meta.get("client_id", ""), d, self.z, self.keys, self.config,
                                  self._report_reject, restored=True)
            except Exception as exc:  # noqa: BLE001 - one broken directory must not stop the others
                _log.error("session %s: cannot restore from %s: %s", sid, d, exc)
                continue
            self.sessions[sid] = s
            self._deadline[sid] = time.monotonic() + TOKEN_SETTLE_S
            _log.info("session %s restored from %s (sim time %.3f s, %d particles) in %.2f s", sid, d,
                      engine.sim_time_s, engine.n_particles, time.monotonic() - t0)

    # ------------------------------------------------------------------ inputs
    def _on_input(self, smp) -> None:
        try:
            parsed = self.keys.parse(str(smp.key_expr))
            session = self.sessions.get(parsed.session)
            if session is None or session.closed:
                self.unknown_session_samples += 1
                self._report_reject(parsed.session, parsed.name,
                                    WireError(f"no session {parsed.session!r} on this server", Error.UNKNOWN_SESSION))
                return
            att = smp.attachment
            session.on_sample(parsed.name, smp.payload.to_bytes(), att.to_bytes() if att is not None else None)
        except Exception:  # noqa: BLE001 - never raise into Zenoh
            _log.exception("input sample on %s could not be handled", smp.key_expr)

    def _report_reject(self, session_id, stream, exc) -> None:
        key = (session_id, stream, getattr(exc, "cause", type(exc).__name__))
        now = time.monotonic()
        if len(self._rejects) > 4096 and key not in self._rejects:
            self._rejects.clear()            # many distinct bogus keys: forget, do not grow
        entry = self._rejects.setdefault(key, [0, -1e9])
        entry[0] += 1
        if now - entry[1] >= _REJECT_LOG_EVERY_S:
            _log.warning("session %s: rejected %s sample (%s; %d so far): %s", session_id, stream, key[2],
                         entry[0], exc)
            entry[1] = now

    # ------------------------------------------------------------------ RPCs
    def _on_query(self, q) -> None:
        try:
            key = str(q.key_expr)
            payload = q.payload.to_bytes() if q.payload is not None else b""
            pool = self._create_pool if key == self.keys.rpc("create_session") else self._rpc_pool
            if key.rsplit("/", 1)[-1] in SLOW_METHODS:
                pool = self._infer_pool
            pool.submit(self._answer, q, key, payload)
        except Exception:  # noqa: BLE001 - e.g. pools shut down while stopping
            _log.exception("query on %s could not be dispatched", q.key_expr)

    def _answer(self, q, key: str, payload: bytes) -> None:
        try:
            reply = self._dispatch(key, payload)
            q.reply(q.key_expr, reply.SerializeToString())
        except (WireError, EngineError) as exc:
            q.reply_err(error_bytes(exc.code, str(exc)))
        except Exception as exc:  # noqa: BLE001 - the server answers, whatever happened
            _log.exception("RPC %s failed", key)
            q.reply_err(error_bytes(Error.INTERNAL, f"server error in {key}: {type(exc).__name__}: {exc}"))
        finally:
            q.drop()

    def _dispatch(self, key: str, payload: bytes):
        try:
            parsed = self.keys.parse(key)
        except ValueError as exc:
            raise WireError(str(exc)) from None
        limit = self.config.max_payload_bytes
        if parsed.session is None:
            if parsed.name == "create_session":
                return self._create(parse_request(CreateSessionRequest, payload, max_bytes=limit))
            if parsed.name == "list_sessions":
                parse_request(ListSessionsRequest, payload, max_bytes=limit)
                with self._lock:
                    sessions = list(self.sessions.values())
                return ListSessionsReply(header=make_header(), server_id=self.config.server_id,
                                         sessions=[s.status(self.config.server_id) for s in sessions])
            raise WireError(f"unknown RPC {parsed.name!r}; methods: create_session, list_sessions")
        if parsed.name not in SESSION_METHODS:
            raise WireError(f"unknown session RPC {parsed.name!r}; methods: {', '.join(SESSION_METHODS)}")
        cls = {"set_task": SetTaskRequest, "infer_fill": InferFillRequest, "infer_blockage": InferBlockageRequest,
               "discrepancy": DiscrepancyRequest, "load_model": LoadModelRequest}.get(parsed.name, SessionRequest)
        req = parse_request(cls, payload, max_bytes=limit, session_id=parsed.session)
        s = self.sessions.get(parsed.session)
        if s is None or s.closed:
            raise WireError(f"no session {parsed.session!r} on this server (list_sessions shows the open ones)",
                            Error.UNKNOWN_SESSION)
        if s.orphaned_since is not None:
            _log.info("session %s: an RPC adopted it again; no longer orphaned", s.id)
        s.orphaned_since = None
        self._deadline[s.id] = time.monotonic() + self.config.orphan_grace_s
        if parsed.name == "meshes":
            return scene_meshes(make_header(s.id), s.meshes())
        if parsed.name == "discrepancy":
            return s.discrepancy(req)
        if parsed.name in SLOW_METHODS:
            return s.infer(parsed.name, req)
        if parsed.name == "load_model":
            s.load_model(req.model_json)
        elif parsed.name == "reset":
            s.reset()
        elif parsed.name == "set_task":
            bad = _non_finite(req.task)
            if bad:
                raise WireError(f"task field {bad} is NaN or infinite", Error.NON_FINITE)
            s.set_task(req.task)
        elif parsed.name == "close":
            self._close(s, "closed by its client")
        return s.status(self.config.server_id)

    def _create(self, req: CreateSessionRequest):
        bad = _non_finite(req.spec)
        if bad:
            raise WireError(f"session spec field {bad} is NaN or infinite", Error.NON_FINITE)
        try:
            sid = validate_session_id(req.session_id) if req.session_id else f"s-{uuid.uuid4().hex[:10]}"
            if req.client_id:
                validate_id(req.client_id, "client id")
        except ValueError as exc:
            raise WireError(str(exc)) from None
        make_detector(req.spec, self.config)        # a bad mask_source or model fails here, before any work
        spec = self._solving_impacts(req.spec) if self.config.solve_impacts else req.spec
        with self._lock:
            if sid in self.sessions or sid in self._creating:
                raise WireError(f"session {sid!r} already exists", Error.ALREADY_EXISTS)
            if len(self.sessions) + len(self._creating) >= self.config.max_sessions:
                raise WireError(f"this server holds its maximum of {self.config.max_sessions} sessions; close one "
                                f"or start it with a larger --max-sessions", Error.RESOURCE_EXHAUSTED)
            self._creating.add(sid)
        try:
            t0 = time.monotonic()
            engine = self.factory(spec, device=spec.device or self.config.device)
            d = sessions_root(self.config.state_dir) / sid
            write_session_files(d, spec, {"session_id": sid, "client_id": req.client_id, "state": "open",
                                              "created_ns": time.time_ns(), "server_id": self.config.server_id})
            s = ServedSession(sid, engine, spec, req.client_id, d, self.z, self.keys, self.config,
                              self._report_reject)
            with self._lock:
                self.sessions[sid] = s
                self._deadline[sid] = time.monotonic() + TOKEN_SETTLE_S
        finally:
            with self._lock:
                self._creating.discard(sid)
        _log.info("session %s created for client %r in %.2f s: %d particles, objects %s", sid, req.client_id,
                  time.monotonic() - t0, engine.n_particles, ", ".join(engine.object_names))
        return s.status(self.config.server_id)

    @staticmethod
    def _solving_impacts(spec):
        """A copy of ``spec`` solving the iterations its containers' longest fall needs
        (``--solve-impacts``); ``spec`` itself when it states enough, or when its scene cannot
        be read (the engine's build then names what is wrong)."""
        from ..scenes.spec import impact_iterations, simulation_settings, solve_with
        try:
            need, stated = impact_iterations(spec.scene), simulation_settings(spec.scene)["iterations"]
        except Exception:  # noqa: BLE001 - the engine's build names what is wrong with the scene
            return spec
        if need <= stated:
            return spec
        out = type(spec)()
        out.CopyFrom(spec)
        solve_with(out.scene, need)
        _log.info("solving %d iterations a step (stated %d) for the falls between the containers of %r", need,
                  stated, spec.scene.name)
        return out

    def _close(self, s: ServedSession, why: str) -> None:
        """Close ``s`` once (a client's close and the orphan timer may race). It leaves the
        session list only after it is marked closed on disk, so a session that is no longer
        listed is never restored after a crash."""
        with self._lock:
            if s.closing:
                return
            s.closing = True
        s.close(final=True)
        with self._lock:
            if self.sessions.get(s.id) is s:
                del self.sessions[s.id]
        _log.info("session %s closed (%s); log %s", s.id, why, s.log.path)

    # ------------------------------------------------------------------ liveliness
    def _on_alive(self, smp) -> None:
        try:
            cid = self.keys.parse(str(smp.key_expr)).name
            if smp.kind == zenoh.SampleKind.PUT:
                self._alive_clients.add(cid)
            else:
                self._alive_clients.discard(cid)
        except Exception:  # noqa: BLE001
            _log.exception("liveliness sample %s", smp.key_expr)

    def _housekeeping(self) -> None:
        while not self._stop.wait(0.2):
            now = time.monotonic()
            for s in list(self.sessions.values()):
                if not s.client_id or s.closed:
                    continue
                if s.client_id in self._alive_clients:
                    if s.orphaned_since is not None:
                        _log.info("session %s: client %s is back", s.id, s.client_id)
                    s.orphaned_since = None
                elif s.orphaned_since is None and now >= self._deadline.get(s.id, 0.0):
                    s.orphaned_since = now
                    _log.info("session %s orphaned: client %s vanished; closing in %g s unless it comes back",
                              s.id, s.client_id, self.config.orphan_grace_s)
                elif s.orphaned_since is not None and now - s.orphaned_since >= self.config.orphan_grace_s:
                    try:
                        self._close(s, f"orphaned for {self.config.orphan_grace_s:g} s")
                    except Exception:  # noqa: BLE001
                        _log.exception("closing orphaned session %s", s.id)
