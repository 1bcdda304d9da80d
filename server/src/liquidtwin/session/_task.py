"""A session's task: checking a pour request against the scene and driving its controller
(PD baseline or MPC through the session's model)."""

from __future__ import annotations

import math

import torch
from google.protobuf import json_format
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..control import PourPID
from ..control.pour import LAND_S, UPRIGHT, PourMPC
from ..control.tilt import PourAxis, pour_axis, tilt_from_upright, tilt_space, turn_pose
from .errors import BAD_REQUEST, INFEASIBLE, UNKNOWN_NAME, EngineError

#: Limits used when a task leaves them at 0: tilt up to 135° at up to 1 rad/s.
DEFAULT_MAX_ANGLE = math.radians(135.0)
DEFAULT_MAX_RATE = 1.0
#: Task.controller values ("" = "pid").
CONTROLLERS = ("", "pid", "mpc")
#: The MPC's horizon (model steps) and normalised step (rad/s per update): bench/control_pour.py's.
MPC_HORIZON = 10
MPC_STEP = 0.5
#: ``PourToVolume.top_up``: pour again when short of the ask by more than the larger of these
#: (ml, share of the ask), at most this many times.
TOPUP_MIN_ML, TOPUP_SHARE, MAX_TOPUPS = 1.0, 0.1, 2


def check_pour(task: pb.Task, names, containers, volumes: dict, capacities: dict) -> tuple[float, float]:
    """(max_angle rad, max_rate rad/s) of a pour task, or EngineError (UNKNOWN_NAME,
    BAD_REQUEST, INFEASIBLE) if the task cannot be done in this scene now. ``volumes``: ml per
    container now; ``capacities``: ml per container to the rim."""
    if task.controller not in CONTROLLERS:
        raise EngineError(BAD_REQUEST, f"unknown controller {task.controller!r}; use 'pid' or 'mpc'")
    p = task.pour
    for role, name in (("source", p.source), ("target", p.target)):
        if name not in names:
            raise EngineError(UNKNOWN_NAME, f"pour {role} {name!r} is not an object of the scene ({', '.join(names)})")
        if name not in containers:
            raise EngineError(BAD_REQUEST, f"pour {role} {name!r} is not a container (its volume is not tracked)")
    if p.source == p.target:
        raise EngineError(BAD_REQUEST, f"pour source and target are the same container {p.source!r}")
    if not (math.isfinite(p.volume_ml) and p.volume_ml > 0):
        raise EngineError(BAD_REQUEST, f"pour volume_ml must be > 0 ml, got {p.volume_ml}")
    if p.top_up and task.controller != "mpc":
        raise EngineError(BAD_REQUEST, "top_up is an option of the 'mpc' pour controller")
    max_angle = p.max_angle_rad or DEFAULT_MAX_ANGLE
    max_rate = p.max_rate_rad_s or DEFAULT_MAX_RATE
    if not (math.isfinite(max_angle) and 0 < max_angle <= math.pi):
        raise EngineError(BAD_REQUEST, f"max_angle_rad must be in (0, π] (0 = default), got {p.max_angle_rad}")
    if not (math.isfinite(max_rate) and max_rate > 0):
        raise EngineError(BAD_REQUEST, f"max_rate_rad_s must be > 0 rad/s (0 = default), got {p.max_rate_rad_s}")
    if p.volume_ml > volumes[p.source]:
        raise EngineError(INFEASIBLE, f"cannot pour {p.volume_ml:.1f} ml: {p.source!r} holds "
                                      f"{volumes[p.source]:.1f} ml now")
    room = capacities[p.target] - volumes[p.target]
    if p.volume_ml > room:
        raise EngineError(INFEASIBLE, f"cannot pour {p.volume_ml:.1f} ml into {p.target!r}: it has room for "
                                      f"{max(room, 0.0):.1f} ml")
    return max_angle, max_rate


class PourTask:
    """A session's pour task and its controller: the PD baseline (:class:`PourPID`, on the
    tracked target volume) or MPC through the session's model (:class:`PourMPC`, from the
    tracked particles, once per frame). Both tilt the source about the same axis
    (:mod:`liquidtwin.control.tilt`), sent with every Control. Reads the engine's state; build
    with :meth:`create`."""

    def __init__(self, task: pb.Task, axis: PourAxis, base_ml: float, max_angle: float, max_rate: float,
                 ctrl, names):
        self.task, self.axis, self.base_ml = task, axis, float(base_ml)
        self.max_angle, self.max_rate, self.ctrl = float(max_angle), float(max_rate), ctrl
        self.src, self.dst = names.index(task.pour.source), names.index(task.pour.target)
        self.control_frame, self.last_sim_t = -1, -1.0
        self.command = (0.0, 0.0, False)            # MPC: (angle rad, rate rad/s, done) of its last update
        # top_up: pours so far after the first, sim time the source came back upright (-1: not
        # upright since the last switch), the task over
        self.topups, self.upright_since, self.finished = 0, -1.0, False

    @property
    def is_mpc(self) -> bool:
        return self.task.controller == "mpc"

    @classmethod
    def create(cls, task: pb.Task, eng, *, state: dict | None = None) -> "PourTask":
        """The task on engine ``eng`` now (EngineError if impossible, see :func:`check_pour`);
        ``state``: a :meth:`state_dict` to continue from (checks skipped: it was accepted)."""
        names = eng.object_names
        if state is None:
            vols = eng.volumes()
            max_angle, max_rate = check_pour(task, names, eng.container_names, vols, eng._capacity)
            base = vols[task.pour.target]
        else:
            limits = state if "max_angle" in state else state["pid"]     # older checkpoints: the PID's
            max_angle, max_rate, base = limits["max_angle"], limits["max_rate"], state["task_base"]
        src, dst = names.index(task.pour.source), names.index(task.pour.target)
        poses = eng._frame_poses
        if state is not None and "pivot_local" in state:
            axis = PourAxis(state["pivot_local"].numpy(), state["axis"].numpy())
        else:
            axis = pour_axis(eng._scene.objects[src].mesh.vertices, poses[src], poses[dst][:3])
        if task.controller == "mpc":
            target_ml = float(state.get("mpc_target_ml", task.pour.volume_ml)) if state else task.pour.volume_ml
            ctrl = cls._mpc(eng, src, dst, axis, max_angle, max_rate, target_ml)
            if state is not None:
                ctrl.load_state_dict(state["mpc"])
        elif state is not None and state.get("pid"):
            ctrl = PourPID.from_state_dict(state["pid"])
        else:
            ctrl = PourPID(task.pour.volume_ml, max_angle, max_rate,
                           angle=min(tilt_from_upright(poses[src]), max_angle))
        out = cls(task, axis, base, max_angle, max_rate, ctrl, names)
        if state is not None:
            out.control_frame = int(state["control_frame"])
            out.last_sim_t = float(state.get("last_sim_t", -1.0))
            out.command = tuple(state.get("command", (0.0, 0.0, False)))
            out.topups, out.upright_since = int(state.get("topups", 0)), float(state.get("upright_since", -1.0))
            out.finished = bool(state.get("finished", False))
        return out

    @classmethod
    def _mpc(cls, eng, src: int, dst: int, axis: PourAxis, max_angle: float, max_rate: float, target_ml: float):
        """A pour MPC for ``target_ml`` more ml in the target, counted from the engine's state now."""
        return PourMPC(eng._model, cls._space(eng, src, axis, max_angle, max_rate),
                       axis.pivot_world(eng._frame_poses[src]), src, dst, eng._scene.objects[src],
                       eng._scene.objects[dst], target_ml, eng._ml_per_particle, state=eng._state,
                       horizon=MPC_HORIZON, step_size=MPC_STEP)

    def _top_up(self, eng, tilt: float) -> None:
        """``top_up``: after a switch, once the source has been upright for ``LAND_S``, pour the
        rest when the tracked target is short of the ask (module constants), else finish."""
        if tilt >= UPRIGHT:
            self.upright_since = -1.0
            return
        if self.upright_since < 0:
            self.upright_since = eng._sim_t
            return
        if eng._sim_t - self.upright_since < LAND_S:
            return
        vols = eng.volumes()
        p = self.task.pour
        short = p.volume_ml - (vols[p.target] - self.base_ml)
        if self.topups >= MAX_TOPUPS or short <= max(TOPUP_MIN_ML, TOPUP_SHARE * p.volume_ml) or vols[p.source] < short:
            self.finished = True
            return
        self.ctrl = self._mpc(eng, self.src, self.dst, self.axis, self.max_angle, self.max_rate, short)
        self.topups, self.upright_since = self.topups + 1, -1.0

    @staticmethod
    def _space(eng, src: int, axis: PourAxis, max_angle: float, max_rate: float):
        pose = eng._frame_poses[src]
        return tilt_space(eng._frame_poses, src, axis.pivot_world(pose), axis.axis, tilt_from_upright(pose),
                          max_angle, max_rate)

    def control(self, eng) -> pb.Control:
        """The command after the engine's latest frame (computed once per frame; header left
        to the service)."""
        poured = eng.volumes()[self.task.pour.target] - self.base_ml
        if self.control_frame != eng._frames:
            if self.is_mpc:
                self.command = self._update_mpc(eng)
            else:
                self.ctrl.update(eng._sim_t, poured)
            self.control_frame = eng._frames
        angle, rate, done = self.command if self.is_mpc else (self.ctrl.angle, self.ctrl.rate, self.ctrl.done)
        pose = eng._frame_poses[self.src]
        pivot = self.axis.pivot_world(pose)
        return pb.Control(object=self.task.pour.source, tilt_angle_rad=angle, tilt_rate_rad_s=rate,
                          achieved_ml=poured, remaining_ml=max(self.task.pour.volume_ml - poured, 0.0), done=done,
                          controller=self.task.controller or "pid", axis_point_m=pivot.tolist(),
                          axis_direction=self.axis.axis.tolist(),
                          pose=turn_pose(pose, pivot, self.axis.axis, angle - tilt_from_upright(pose)).tolist(),
                          linear_velocity_m_s=[0.0, 0.0, 0.0], angular_velocity_rad_s=(rate * self.axis.axis).tolist())

    def _update_mpc(self, eng) -> tuple[float, float, bool]:
        pose = eng._frame_poses[self.src]
        tilt = tilt_from_upright(pose)
        if self.task.pour.top_up and self.ctrl.done and not self.finished:
            self._top_up(eng, tilt)
        elapsed = 1 if self.last_sim_t < 0 else max(1, int(round((eng._sim_t - self.last_sim_t) / eng.dt)))
        # the session's model now (a loaded extension changes it, and a refill its ml per particle)
        self.ctrl.model = self.ctrl.mpc.model = eng._model
        self.ctrl.ml = eng._ml_per_particle
        with torch.enable_grad():                  # the engine runs without gradients
            u = self.ctrl.update(eng._state, torch.tensor([tilt], dtype=torch.float64),
                                 self._space(eng, self.src, self.axis, self.max_angle, self.max_rate),
                                 self.axis.pivot_world(pose), elapsed)
        self.last_sim_t = eng._sim_t
        rate = float(u[0])
        done = self.finished if self.task.pour.top_up else bool(self.ctrl.done)
        return min(max(tilt + rate * elapsed * eng.dt, 0.0), self.max_angle), rate, done

    def state_dict(self) -> dict:
        """Tensors, numbers and strings (the engine checkpoint's task keys)."""
        return {"task": task_to_str(self.task), "task_base": self.base_ml, "control_frame": int(self.control_frame),
                "max_angle": self.max_angle, "max_rate": self.max_rate, "last_sim_t": self.last_sim_t,
                "command": [float(self.command[0]), float(self.command[1]), bool(self.command[2])],
                "pivot_local": torch.as_tensor(self.axis.pivot_local), "axis": torch.as_tensor(self.axis.axis),
                "pid": {} if self.is_mpc else self.ctrl.state_dict(),
                "mpc": self.ctrl.state_dict() if self.is_mpc else {},
                "topups": int(self.topups), "upright_since": float(self.upright_since), "finished": bool(self.finished),
                "mpc_target_ml": float(self.ctrl.target_ml) if self.is_mpc else 0.0}


def create_task(task: pb.Task, eng, *, state: dict | None = None):
    """The session task for ``task`` (a pour, catch or send) on engine ``eng`` now (EngineError
    if impossible); ``state``: its checkpoint keys to continue from."""
    from ._motion_tasks import CatchTask, SendTask
    kind = task.WhichOneof("kind")
    cls = {"pour": PourTask, "catch_stream": CatchTask, "send": SendTask}.get(kind)
    if cls is None:
        raise EngineError(BAD_REQUEST, f"unknown task kind {kind!r}")
    return cls.create(task, eng, state=state)


def task_to_str(task: pb.Task) -> str:
    return json_format.MessageToJson(task)


def task_from_str(text: str) -> pb.Task:
    return json_format.Parse(text, pb.Task())
