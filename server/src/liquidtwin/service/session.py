"""A served session: inputs in, one worker thread advancing the engine, outputs out.

:class:`ServedSession` owns one :class:`~liquidtwin.session.SessionEngine`, its
:class:`~.inbox.Inbox`, its MCAP log and checkpoints, and the Zenoh publishers of its
output streams. The worker handles one frame at a time (docs/service.md): calibrations
and camera poses → ``engine.advance`` → ``engine.correct`` when a mask applies → publish
particles, volumes, overlay (with a mask), control (with a task), metrics. An exception in
the worker marks the session ``failed`` (a reset revives it); the server keeps serving.
"""

from __future__ import annotations

import logging
import threading
import time

import zenoh
from liquidtwin_proto import (PROTOCOL_VERSION, Header, InferenceReply, SessionStatus, Task, TrackingMode, encode_attachment,
                              now_ns)

from ..session import EngineError
from ..session.errors import BAD_REQUEST, INFEASIBLE, UNKNOWN_NAME
from .checkpoint import load_checkpoint, mark_closed, save_checkpoint
from .detector import make_detector
from .discrepancy import discrepancy_reply, model_json, parse_model
from .inbox import Frame, Inbox
from .inputs import INPUT_TYPES, InputChecker, InputError, session_seconds
from .log import SessionLog
from .outputs import container_volumes, metrics_message, overlay_image, particles_cloud, volumes_message

_log = logging.getLogger("liquidtwin.serve")
OUTPUTS = ("particles", "volumes", "overlay", "control", "metrics")
_MODE_NAMES = {TrackingMode.Value("OPEN_LOOP"): "open_loop", TrackingMode.Value("WARP_FIELD"): "warp_field",
               TrackingMode.Value("MAP_FILTER"): "map_filter"}


class ServedSession:
    """One live session (see the module doc).

    Args:
      session_id, engine, spec (SessionSpec), client_id: what it serves and for whom.
      directory: its folder under the state dir (log segments, checkpoint, spec.pb).
      zsession, keys: the server's Zenoh session and key builder (outputs are published).
      config: the ServeConfig. on_reject(session_id, stream, InputError): rate-limited logging.
      restored: it was restored from ``directory`` (its checkpoint is loaded here).
    """

    def __init__(self, session_id, engine, spec, client_id, directory, zsession, keys, config, on_reject,
                 restored=False):
        self.id, self.engine, self.spec, self.client_id = session_id, engine, spec, client_id
        self.dir, self.config, self.restored, self._on_reject = directory, config, restored, on_reject
        self.lock = threading.RLock()           # serialises every engine call
        self.failed: str | None = None
        self.closed = False
        self.closing = False                    # the server claimed its close (once)
        self.orphaned_since: float | None = None
        self.task: Task | None = None
        self._first_ns: int | None = None
        self._episode_ns = 0                    # server receive time of the last reset, ns
        self._out_seq = {s: 0 for s in OUTPUTS}
        service = {}
        if restored:
            ckpt = load_checkpoint(directory)
            if ckpt is not None:
                engine.load_state_dict(ckpt["engine"])
                service = ckpt["service"]
                self._first_ns = service["first_ns"] if service["first_ns"] >= 0 else None
                self._out_seq.update(service["out_seq"])
                self.task = Task.FromString(bytes.fromhex(service["task"])) if service["task"] else None
                self._episode_ns = int(service.get("episode_ns", 0))
        self.detector = make_detector(spec, config)
        self.inbox = Inbox(service.get("counters"), service.get("last"), keep_images=self.detector is not None)
        cams = {n: engine.camera_size(n) for n in engine.camera_names}
        self.checker = InputChecker(engine.object_names, cams, config.max_payload_bytes)
        self.log = SessionLog(directory, spec)
        # BLOCK: under CPU load Zenoh's default (DROP) loses outputs while its queue waits for the
        # transmit thread; blocking only happens when a link's queue is full (a stalled peer)
        self._pubs = {s: zsession.declare_publisher(keys.stream_out(session_id, s),
                                                    congestion_control=zenoh.CongestionControl.BLOCK)
                      for s in OUTPUTS}
        self.last_input = time.monotonic()
        self._dirty, self._last_ckpt = not restored, time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"session-{session_id}", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ inputs (Zenoh callback)
    def on_sample(self, stream: str, payload: bytes, attachment: bytes | None) -> None:
        """Check, log and queue one input sample; count it when refused."""
        received = now_ns()
        self.last_input = time.monotonic()
        try:
            sample = self.checker.check(self.id, stream, payload, attachment)
        except InputError as exc:
            self.inbox.count("rejected")
            self._on_reject(self.id, stream, exc)
            return

        def accepted(s):
            if s.stream == "camera":
                self.checker.learn(s.item)
            self.log.write(f"/in/{stream}", INPUT_TYPES[stream], received, s.header.stamp_ns, s.header.seq,
                           data=s.payload)

        self.inbox.accept(sample, received, accepted)

    # ------------------------------------------------------------------ worker
    def _run(self) -> None:
        while not self._stop.is_set():
            frame = None if self.failed else self.inbox.take(0.2, self.config.mask_max_age_s, self._stop)
            if frame is None:
                if self.failed:
                    self._stop.wait(0.2)
            else:
                try:
                    self._process(frame)
                except Exception as exc:  # noqa: BLE001 - a bug here must not reach other sessions
                    self.failed = f"{type(exc).__name__}: {exc}"
                    _log.exception("session %s failed on the frame at stamp %d; it stops until reset",
                                   self.id, frame.sample.header.stamp_ns)
            if self._dirty and time.monotonic() - self._last_ckpt >= self.config.checkpoint_s:
                self.checkpoint()

    def _reject(self, stream: str, exc: Exception, cause: str) -> None:
        self.inbox.count("rejected")
        self._on_reject(self.id, stream, InputError(str(exc), cause, getattr(exc, "code", 1)))

    def _process(self, frame: Frame) -> None:
        header, item = frame.sample.header, frame.sample.item
        stamp = int(header.stamp_ns)
        eng = self.engine
        with self.lock:
            if frame.images and self.detector is not None:
                self._detect(frame, stamp)
            for cam in frame.cameras:
                try:
                    eng.set_camera(cam.name, K=cam.K, D=cam.D, width=cam.width, height=cam.height)
                except EngineError as exc:
                    self._reject("camera", exc, "calibration")
            for name, pose in item.cameras.items():
                try:
                    eng.set_camera(name, pose=pose)
                except EngineError as exc:
                    self._reject("poses", exc, "camera_pose")
            if self._first_ns is None:
                self._first_ns = stamp
            try:
                res = eng.advance(session_seconds(stamp, self._first_ns), item.objects,
                                  max_steps=self.config.max_steps_per_frame)
            except EngineError as exc:
                self._reject("poses", exc, "frame")
                return
            corr = None
            if frame.mask is not None:
                try:
                    corr = eng.correct(*frame.mask)
                except EngineError as exc:
                    self._reject("mask", exc, "mask_unusable")
            pos, speed, vols = eng.positions(), eng.speeds(), eng.volumes()
            mask_vols = eng.mask_volumes()          # issue 5: model-based estimate → ContainerVolume.mask_ml
            control = eng.control()
            particles = eng.n_particles
            self._dirty = True
        self.inbox.count("frames_done")
        out = [("particles", particles_cloud(pos, speed, stamp)), ("volumes", volumes_message(self._header(stamp), vols, mask_vols))]
        if corr is not None:
            out.append(("overlay", overlay_image(corr.overlay, frame.mask[0], stamp)))
        if control is not None:
            control.header.CopyFrom(self._header(stamp))
            out.append(("control", control))
        lag_ms = (now_ns() - frame.received_ns) / 1e6
        out.append(("metrics", metrics_message(self._header(stamp), input_seq=header.seq, frame=res,
                                               particles=particles, counters=self.inbox.state()["counters"],
                                               lag_ms=lag_ms, correction=corr,
                                               camera=frame.mask[0] if corr is not None else "")))
        for stream, msg in out:
            self._publish(stream, msg, stamp)

    def _detect(self, frame: Frame, stamp: int) -> None:
        """Run the detector on every pending image in order; the newest one's mask is the
        frame's observation (if fresh enough and no streamed mask is newer)."""
        newest = None
        for t_img, camera, rgb in frame.images:
            try:
                newest = (t_img, camera, self.detector(camera, rgb))
            except ValueError as exc:               # e.g. a camera's image size changed mid-stream
                self._reject("image", exc, "detector")
        if newest is not None and stamp - newest[0] <= self.config.mask_max_age_s * 1e9:
            frame.mask = (newest[1], newest[2])

    def _header(self, stamp: int) -> Header:
        return Header(session_id=self.id, stamp_ns=stamp, version=PROTOCOL_VERSION)

    def _publish(self, stream: str, msg, stamp: int) -> None:
        seq = self._out_seq[stream]
        self._out_seq[stream] = seq + 1
        head = Header(session_id=self.id, seq=seq, stamp_ns=stamp, version=PROTOCOL_VERSION)
        if hasattr(msg, "header"):
            msg.header.seq = seq
        data = msg.SerializeToString()
        self.log.write(f"/out/{stream}", msg, now_ns(), stamp, seq, data=data)    # logged first: a kill
        self._pubs[stream].put(data, attachment=encode_attachment(head))           # never loses a sent output

    # ------------------------------------------------------------------ checkpoints
    def checkpoint(self) -> None:
        """Write checkpoint.pt now (engine state + counters, stamps, output sequence numbers)."""
        with self.lock:
            engine_state = self.engine.state_dict()
            service = {**self.inbox.state(), "first_ns": -1 if self._first_ns is None else int(self._first_ns),
                       "out_seq": dict(self._out_seq), "episode_ns": int(self._episode_ns),
                       "task": self.task.SerializeToString().hex() if self.task is not None else ""}
            self._dirty = False
            self._last_ckpt = time.monotonic()
        save_checkpoint(self.dir, engine_state, service)

    # ------------------------------------------------------------------ RPCs
    @property
    def state(self) -> str:
        if self.closed:
            return "closed"
        if self.failed:
            return "failed"
        if self.orphaned_since is not None:
            return "orphaned"
        if time.monotonic() - self.last_input > self.config.idle_after_s:
            return "idle"
        return "running"

    def status(self, server_id: str) -> SessionStatus:
        """The session's SessionStatus now."""
        with self.lock:
            try:
                vols = self.engine.volumes() if not self.closed and not self.failed else {}
                mask_vols = self.engine.mask_volumes() if vols else {}      # issue 5: mask_ml
            except Exception:  # noqa: BLE001 - a status must answer even when the engine cannot
                _log.exception("session %s: volumes for its status failed", self.id)
                vols, mask_vols = {}, {}
            st = SessionStatus(session_id=self.id, state=self.state, spec=self.spec,
                               sim_time_s=self.engine.sim_time_s, particles=self.engine.n_particles,
                               volumes=container_volumes(vols, mask_vols), log_path=str(self.log.path),
                               checkpoint_path=str(self.dir / "checkpoint.pt"), restored=self.restored,
                               server_id=server_id, model_json=model_json(getattr(self.engine, "extension", None)))
        st.header.CopyFrom(Header(session_id=self.id, stamp_ns=now_ns(), version=PROTOCOL_VERSION))
        st.frames_done = self.inbox.state()["counters"]["frames_done"]
        if self.task is not None:
            st.task.CopyFrom(self.task)
        return st

    def reset(self) -> None:
        """Back to the initial fill at time 0 (task cleared, counters kept; failed → running)."""
        with self.lock:
            self.engine.reset()
            self.inbox.clear()
            if self.detector is not None:
                self.detector.reset()
            self._first_ns, self.task, self.failed = None, None, None
            self._episode_ns = now_ns()
            self._dirty = True

    def set_task(self, task: Task) -> None:
        """Set or (empty task) cancel the pour task; EngineError when impossible."""
        with self.lock:
            self.engine.set_task(task)
            self.task = None if task.WhichOneof("kind") is None else Task.FromString(task.SerializeToString())
            self._dirty = True

    def meshes(self) -> dict:
        with self.lock:
            return self.engine.meshes()

    def _recording(self):
        """The inputs logged since the last reset as a Recording (EngineError INFEASIBLE: none yet)."""
        from .history import NoFramesError, session_recording
        with self.lock:
            cameras = self.engine.camera_calibrations()
        try:
            return session_recording(self.dir, self.spec, self.engine.object_names, cameras, since_ns=self._episode_ns)
        except NoFramesError as exc:
            raise EngineError(INFEASIBLE, f"session {self.id}: {exc}") from None

    def infer(self, method: str, req) -> InferenceReply:
        """``infer_fill`` / ``infer_blockage`` on the inputs logged since the last reset: the
        hypothesis bank runs on this thread (the session's worker carries on)."""
        from ..inference import infer_blockage, infer_fill
        from .history import inference_reply
        tracking = self.spec.tracking
        rec = self._recording()
        mode = _MODE_NAMES.get(req.tracking or tracking, "warp_field")
        try:
            if method == "infer_fill":
                post = infer_fill(rec, container=req.container or None,
                                  fractions=tuple(req.fractions) or None, tracking=mode)
            else:
                post = infer_blockage(rec, obj=req.object or None, tracking=mode)
        except KeyError as exc:
            raise EngineError(UNKNOWN_NAME, str(exc.args[0] if exc.args else exc)) from None
        except ValueError as exc:
            raise EngineError(BAD_REQUEST, str(exc)) from None
        return inference_reply(self._header(now_ns()), post)

    def discrepancy(self, req):
        """``discrepancy`` (a DiscrepancyReply) on the inputs logged since the last reset; runs on
        this thread (the session's worker carries on)."""
        return discrepancy_reply(self._header(now_ns()), self._recording(), req)

    def load_model(self, text: str) -> None:
        """Run the model file ``text`` (JSON) from now on; EngineError when it is not a valid one
        (the session keeps its current model). A fill_error refill settles outside the lock."""
        prepared = self.engine.prepare_extension(parse_model(text))
        with self.lock:
            self.engine.load_extension(prepared)
            self._dirty = True
        _log.info("session %s: model %s loaded", self.id, model_json(prepared.ext) or "none")

    def close(self, final: bool = True) -> None:
        """Stop the worker, write a last checkpoint, close the log and publishers. ``final``:
        the session ends (marked closed, not restored); else the server is shutting down."""
        self._stop.set()
        self.inbox.wake()
        if threading.current_thread() is not self._thread:
            self._thread.join(30)
        try:
            self.checkpoint()
        except Exception:  # noqa: BLE001 - a failed engine may not serialise; the log is what counts
            _log.exception("session %s: final checkpoint failed", self.id)
        self.closed = True
        self.log.close()
        for p in self._pubs.values():
            p.undeclare()
        if final:
            mark_closed(self.dir)
