"""One server session seen from the robot: publish inputs, receive outputs, call its RPCs.

Created by :meth:`Client.create_session` or :meth:`Client.session`. Inputs go to
``<prefix>/<session>/in/<stream>``, each sample with a liquidtwin Header attachment
(``seq`` counts per stream from 0, ``stamp_ns`` = the time the content refers to).
A stamp's camera / mask / image samples must be sent **before** its poses sample: a poses
sample is a frame and makes the server advance to its stamp (docs/service.md).
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np
import zenoh
from liquidtwin_proto import (IN_STREAMS, OUT_STREAMS, DiscrepancyReply, DiscrepancyRequest, InferBlockageRequest,
                              InferenceReply, InferFillRequest, LoadModelRequest, SceneMeshes, SessionRequest,
                              SessionStatus, SetTaskRequest, Task,
                              decode_attachment, encode_attachment, make_header, now_ns, unpack_array)

from .connection import RPC_TIMEOUT_S, Client, tracking_mode

#: Inference RPCs simulate every hypothesis over the session's frames: allow minutes.
INFER_TIMEOUT_S = 600.0
from .messages import (Output, decode_output, encode_camera, encode_image, encode_mask,
                       encode_poses)
from .models import DISCREPANCY_TIMEOUT_S, Discrepancy, discrepancy_result, model_text

_log = logging.getLogger(__name__)
#: Default capacity of the outputs queue; when full the oldest output is dropped.
QUEUE_SIZE = 4096


@dataclass(frozen=True)
class ObjectMeshArrays:
    """One scene object's surface: vertices (V, 3) float32 m in the object's frame, faces
    (F, 3) uint32 vertex indices, and whether the object is a container."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    container: bool


class SessionHandle:
    """A session on the server. Thread-safe to publish from one thread while outputs
    arrive on Zenoh's threads.

    Attributes:
        session_id: the session's id. last_status: the latest SessionStatus received.
        dropped_outputs: outputs dropped because the :meth:`outputs` queue was full.
        bad_outputs: output samples that failed to decode (bad header or payload).
    """

    def __init__(self, client: Client, session_id: str, status: SessionStatus | None,
                 queue_size: int = QUEUE_SIZE):
        self.client, self.session_id, self.last_status = client, session_id, status
        self.dropped_outputs = self.bad_outputs = 0
        self._callbacks: dict[str, list[Callable[[Output], None]]] = {s: [] for s in OUT_STREAMS}
        self._queue: queue.Queue[Output] = queue.Queue(maxsize=queue_size)
        self._lock = threading.Lock()
        self._seq = dict.fromkeys(IN_STREAMS, 0)
        keys = client.keys
        # BLOCK: a congested link delays an input rather than losing it silently (Zenoh's
        # default drops); staleness is the server's business (dropped_stale).
        self._publishers = {
            s: client.zenoh.declare_publisher(keys.stream_in(session_id, s),
                                              congestion_control=zenoh.CongestionControl.BLOCK)
            for s in IN_STREAMS}
        self._subscriber = client.zenoh.declare_subscriber(
            keys.stream_out(session_id, "*"), self._on_sample)
        self._detached = False

    # -- inputs ----------------------------------------------------------------------------
    def publish_camera(self, name: str, K, D, width: int, height: int,
                       stamp_ns: int | None = None) -> int:
        """Send a camera's intrinsics: K (3, 3) pixels, D (5,) plumb_bob, image size in
        pixels. Returns the sample's seq."""
        stamp = _stamp(stamp_ns)
        return self._put("camera", encode_camera(name, K, D, width, height, stamp), stamp)

    def publish_poses(self, poses: Mapping[str, object], stamp_ns: int | None = None) -> int:
        """Send a frame: ``{name: (7,) pose}`` of objects (object → world) and/or cameras
        (camera → world, OpenCV frame); tx, ty, tz in m, unit quaternion qx, qy, qz, qw.
        Objects not named keep their last pose. Returns the sample's seq (= the answering
        ``Metrics.input_seq``)."""
        stamp = _stamp(stamp_ns)
        return self._put("poses", encode_poses(poses, stamp), stamp)

    def publish_mask(self, camera: str, mask, stamp_ns: int | None = None) -> int:
        """Send a liquid mask (H, W) bool or uint8 (nonzero = liquid) seen by ``camera``;
        its size must equal the camera's calibration."""
        stamp = _stamp(stamp_ns)
        return self._put("mask", encode_mask(camera, mask, stamp), stamp)

    def publish_image(self, camera: str, data: bytes, format: str = "jpeg",
                      stamp_ns: int | None = None) -> int:
        """Send an RGB frame of ``camera`` already compressed as ``format`` ("jpeg"/"png")."""
        stamp = _stamp(stamp_ns)
        return self._put("image", encode_image(camera, data, format, stamp), stamp)

    def publish_raw(self, stream: str, payload: bytes, stamp_ns: int) -> int:
        """Send an already-encoded Foxglove message on input ``stream`` (poses, camera,
        mask, image) with a Header of ``stamp_ns`` (ns since the Unix epoch)."""
        if stream not in IN_STREAMS:
            raise ValueError(f"unknown input stream {stream!r}; expected one of {IN_STREAMS}")
        return self._put(stream, bytes(payload), _stamp(stamp_ns))

    def _put(self, stream: str, message, stamp_ns: int) -> int:
        if self._detached:
            raise RuntimeError(f"session {self.session_id!r} handle is closed")
        payload = message if isinstance(message, bytes) else message.SerializeToString()
        with self._lock:
            seq = self._seq[stream]
            self._seq[stream] = seq + 1
            header = make_header(self.session_id, seq, stamp_ns)
            self._publishers[stream].put(payload, attachment=encode_attachment(header))
        return seq

    # -- outputs ---------------------------------------------------------------------------
    def on(self, stream: str, callback: Callable[[Output], None]) -> None:
        """Call ``callback(Output)`` for every sample of output ``stream`` (particles,
        volumes, control, overlay, metrics), on a Zenoh thread: keep it short."""
        if stream not in OUT_STREAMS:
            raise ValueError(f"unknown output stream {stream!r}; expected one of {OUT_STREAMS}")
        self._callbacks[stream].append(callback)

    def outputs(self, timeout: float | None = 1.0) -> Iterator[Output]:
        """Iterate over received outputs in arrival order; stops after ``timeout`` seconds
        without one (None: never stops). The queue is bounded: see ``dropped_outputs``."""
        while True:
            try:
                yield self._queue.get(timeout=timeout)
            except queue.Empty:
                return

    def next_output(self, timeout: float | None = None) -> Output | None:
        """The next received output, waiting up to ``timeout`` seconds (None: forever);
        None when none came."""
        try:
            return self._queue.get(timeout=timeout) if timeout is None or timeout > 0 \
                else self._queue.get_nowait()
        except queue.Empty:
            return None

    def _on_sample(self, sample) -> None:
        received = now_ns()
        try:
            parsed = self.client.keys.parse(str(sample.key_expr))
            att = sample.attachment
            header = decode_attachment(att.to_bytes() if att is not None else None,
                                       self.session_id)
            payload = sample.payload.to_bytes()
            out = Output(parsed.name, header, decode_output(parsed.name, payload), payload,
                         received)
        except Exception:  # a malformed sample must not kill Zenoh's callback thread
            self.bad_outputs += 1
            return
        for cb in list(self._callbacks[out.stream]):
            try:
                cb(out)
            except Exception:  # a user's bug must not stop the other callbacks
                _log.exception("output callback %r failed on %s", cb, out.stream)
        while True:
            try:
                self._queue.put_nowait(out)
                return
            except queue.Full:
                try:
                    self._queue.get_nowait()
                    self.dropped_outputs += 1
                except queue.Empty:
                    pass

    # -- RPCs ------------------------------------------------------------------------------
    def status(self, timeout: float = RPC_TIMEOUT_S) -> SessionStatus:
        """The session's SessionStatus (state, sim time, frames done, volumes, task)."""
        return self._rpc("status", SessionRequest(header=self._header()), timeout)

    def reset(self, timeout: float = RPC_TIMEOUT_S) -> SessionStatus:
        """Put the liquid back to the initial fill (counters are kept)."""
        return self._rpc("reset", SessionRequest(header=self._header()), timeout)

    def set_pour_task(self, source: str, target: str, volume_ml: float,
                      max_angle_rad: float = 0.0, max_rate_rad_s: float = 0.0,
                      controller: str = "pid", top_up: bool = False,
                      timeout: float = RPC_TIMEOUT_S) -> SessionStatus:
        """Ask the controller to pour ``volume_ml`` (ml) from container ``source`` into
        ``target`` by tilting ``source``; limits: tilt angle (rad from upright) and rate
        (rad/s), 0 = the server's defaults. ``top_up`` ("mpc" only): pour again when the
        tracked target ends short of the ask. Commands arrive on the ``control`` stream."""
        if not np.isfinite(volume_ml) or volume_ml <= 0:
            raise ValueError(f"volume_ml must be a positive number of millilitres, got {volume_ml}")
        task = Task(controller=controller)
        task.pour.source, task.pour.target = source, target
        task.pour.volume_ml = float(volume_ml)
        task.pour.max_angle_rad = float(max_angle_rad)
        task.pour.max_rate_rad_s = float(max_rate_rad_s)
        task.pour.top_up = bool(top_up)
        return self._rpc("set_task", SetTaskRequest(header=self._header(), task=task), timeout)

    def set_catch_task(self, source: str, catcher: str, max_speed_m_s: float = 0.0, range_m: float = 0.0,
                       controller: str = "mpc", timeout: float = RPC_TIMEOUT_S) -> SessionStatus:
        """Ask the controller to slide container ``catcher`` along world x under the liquid
        falling from ``source`` (which someone else moves); limits: speed (m/s) and range either
        way from where the catcher is now (m), 0 = the server's defaults. ``controller``: "mpc"
        or "policy" (the server's learned catching policy: one network evaluation a frame).
        Each Control's ``pose`` is where the catcher should be at the next frame."""
        task = Task(controller=controller)
        task.catch_stream.source, task.catch_stream.catcher = source, catcher
        task.catch_stream.max_speed_m_s, task.catch_stream.range_m = float(max_speed_m_s), float(range_m)
        return self._rpc("set_task", SetTaskRequest(header=self._header(), task=task), timeout)

    def set_send_task(self, obj: str, target: str, max_angle_rad: float = 0.0, max_rate_rad_s: float = 0.0,
                      timeout: float = RPC_TIMEOUT_S) -> SessionStatus:
        """Ask the controller to tilt ``obj`` (a plate holding liquid) about world x and z so the
        liquid lands in container ``target``; limits: tilt about each axis (rad) and rate
        (rad/s), 0 = the server's defaults. Each Control's ``pose`` is where ``obj`` should be
        at the next frame."""
        task = Task(controller="mpc")
        task.send.object, task.send.target = obj, target
        task.send.max_angle_rad, task.send.max_rate_rad_s = float(max_angle_rad), float(max_rate_rad_s)
        return self._rpc("set_task", SetTaskRequest(header=self._header(), task=task), timeout)

    def cancel_task(self, timeout: float = RPC_TIMEOUT_S) -> SessionStatus:
        """Cancel the current task (an empty Task)."""
        return self._rpc("set_task", SetTaskRequest(header=self._header(), task=Task()), timeout)

    def meshes(self, timeout: float = RPC_TIMEOUT_S) -> list[ObjectMeshArrays]:
        """The scene objects' triangle meshes (object frames), for drawing."""
        key = self.client.keys.rpc("meshes", self.session_id)
        reply = self.client.call(key, SessionRequest(header=self._header()), SceneMeshes, timeout)
        return [ObjectMeshArrays(m.name, unpack_array(m.vertices), unpack_array(m.faces),
                                 m.container) for m in reply.objects]

    def infer_fill(self, fractions=(), container: str = "", tracking: str = "",
                   timeout: float = INFER_TIMEOUT_S) -> Inference:
        """How full was ``container`` (default: the scene's filled one) when the session's frames
        began? Each initial fill fraction of its capacity (default 0, 0.3, 0.6, 0.9) is simulated
        over the frames sent since the last reset and scored against their masks (SPEC §3).
        ``tracking``: "open_loop", "warp_field" or "map_filter" inside each hypothesis (default:
        the session's). Takes seconds to minutes; the session keeps running meanwhile."""
        fr = [float(f) for f in fractions]
        if any(not (0.0 <= f <= 1.0) for f in fr):
            raise ValueError(f"fill fractions must be in [0, 1], got {fr}")
        req = InferFillRequest(header=self._header(), session_id=self.session_id, container=container,
                               fractions=fr, tracking=_tracking_mode(tracking))
        return self._infer("infer_fill", req, timeout)

    def infer_blockage(self, obj: str = "", tracking: str = "", timeout: float = INFER_TIMEOUT_S) -> Inference:
        """Which leg of the scene's pipe junction (object ``obj``, default the scene's
        pipe_junction) is blocked: none, left/right × partial/full, scored as infer_fill does."""
        req = InferBlockageRequest(header=self._header(), session_id=self.session_id, object=obj,
                                   tracking=_tracking_mode(tracking))
        return self._infer("infer_blockage", req, timeout)

    def _infer(self, method: str, req, timeout: float) -> Inference:
        key = self.client.keys.rpc(method, self.session_id)
        reply = self.client.call(key, req, InferenceReply, timeout)
        over = unpack_array(reply.probability_over_time) if reply.probability_over_time.shape else np.zeros((0, 0))
        return Inference({h.name: h.probability for h in reply.hypotheses},
                         {h.name: h.log_likelihood for h in reply.hypotheses}, reply.best,
                         np.asarray(reply.times_s), over, int(reply.frames), float(reply.wall_s))

    def discrepancy(self, camera: str | None = None, candidates=None, null_runs: int | None = None,
                    calibrate: bool | None = None, timeout: float = DISCREPANCY_TIMEOUT_S) -> Discrepancy:
        """What does the session's model get wrong on the frames sent since the last reset, and
        which model extension explains it (``liquidtwin discrepancy`` on the session's own log)?
        ``camera``: whose masks (default the first with masks); ``candidates``: names to try
        (default all); ``null_runs``: base-model realisations for the false-discovery null;
        ``calibrate``: fit λ_v, λ_c first (None: the analysis's defaults). Takes minutes."""
        req = DiscrepancyRequest(header=self._header(), session_id=self.session_id, camera=camera or "",
                                 candidates=list(candidates or ()))
        if null_runs is not None:
            if isinstance(null_runs, bool) or int(null_runs) != null_runs or null_runs < 0:
                raise ValueError(f"null_runs must be a whole number >= 0, got {null_runs!r}")
            req.null_runs = int(null_runs)
        if calibrate is not None:
            req.calibrate = bool(calibrate)
        key = self.client.keys.rpc("discrepancy", self.session_id)
        return discrepancy_result(self.client.call(key, req, DiscrepancyReply, timeout))

    def load_model(self, model, timeout: float = RPC_TIMEOUT_S) -> SessionStatus:
        """Run a model extension from now on: ``model`` a model file dict (``Discrepancy.model``),
        an ``Extension``, JSON text or a model file path. The reply's ``model_json`` names it;
        a reset keeps it. The server refuses an invalid one (ServerError BAD_REQUEST)."""
        req = LoadModelRequest(header=self._header(), session_id=self.session_id, model_json=model_text(model))
        return self._rpc("load_model", req, timeout)

    def close(self, timeout: float = RPC_TIMEOUT_S) -> SessionStatus:
        """Close the session on the server (state "closed") and release this handle."""
        try:
            return self._rpc("close", SessionRequest(header=self._header()), timeout)
        finally:
            self.detach()

    def detach(self) -> None:
        """Stop publishing and receiving without closing the session on the server."""
        if self._detached:
            return
        self._detached = True
        self._subscriber.undeclare()
        for pub in self._publishers.values():
            pub.undeclare()

    def _rpc(self, method: str, request, timeout: float) -> SessionStatus:
        key = self.client.keys.rpc(method, self.session_id)
        status = self.client.call(key, request, SessionStatus, timeout)
        self.last_status = status
        return status

    def _header(self):
        return self.client._header(self.session_id)

    def __enter__(self) -> SessionHandle:
        return self

    def __exit__(self, *exc) -> None:
        if not self._detached:
            self.close()


@dataclass(frozen=True)
class Inference:
    """Result of ``infer_fill`` / ``infer_blockage``: ``probability`` and ``log_likelihood``
    per hypothesis name, the ``best`` one, the posterior after each mask frame
    (``times_s`` (T,) s, ``over_time`` (T, K) in the dicts' order), frames scored, wall s."""

    probability: dict
    log_likelihood: dict
    best: str
    times_s: np.ndarray
    over_time: np.ndarray
    frames: int
    wall_s: float


def _tracking_mode(name: str) -> int:
    return 0 if name in ("", None) else tracking_mode(name)     # 0: the session's own


def _stamp(stamp_ns: int | None) -> int:
    if stamp_ns is None:
        return now_ns()
    if isinstance(stamp_ns, bool) or not isinstance(stamp_ns, (int, np.integer)):
        raise ValueError(f"stamp_ns must be an integer ns since the Unix epoch, got {stamp_ns!r}")
    if not 0 <= int(stamp_ns) < 2**63:
        raise ValueError(f"stamp_ns must be in [0, 2**63), got {stamp_ns}")
    return int(stamp_ns)
