"""A session's catch and send tasks (thesis §8.3.3's catching and plate scenes, served): MPC
with gradients through the session's model, from the tracked particles, one update per frame.

- ``catch_stream``: slide the catcher along world x under what falls from the source. The
  source is someone else's: its poses of the last two updates are extrapolated at the same
  twist (:func:`liquidtwin.control.catch.extrapolate_pose`) for the rollouts and the
  first-landing prediction. ``controller = "policy"`` runs the shipped learned catching
  policy (:mod:`liquidtwin.control.policy`, thesis §8.3.4) on the session's particles
  instead: one network evaluation per frame, no rollout.
- ``send``: tilt an object the liquid rests on about world x and z through its origin so the
  liquid lands in the target (the plate MPC's loss, :func:`liquidtwin.control.plate.send_loss`,
  over the particles the object held when the task was set; the lookahead follows their
  amount, :func:`liquidtwin.control.plate.lookahead_for`).

Each Control carries the commanded pose at the next frame and the twist that takes the object
there (linear velocity of ``axis_point_m`` and angular velocity about it).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..control.catch import FALLING_MIN, MAX_SPEED, RANGE, CatchLoss, CatchMPC, CatchParts, extrapolate_pose, \
    slide_space
from ..control.mpc import MPC
from ..control.plate import MAX_RATE, MAX_TILT, STEP_SIZE, UPRIGHT_WEIGHT, aim_point, lookahead_for, send_loss, \
    step_for, tilt2_of, tilt2_space
from ..scenes.liquid_level import held
from ._task import task_to_str
from .errors import BAD_REQUEST, INFEASIBLE, UNKNOWN_NAME, EngineError

#: The MPCs' horizon (model steps) and normalised steps (control units per update): run_catch's
#: and run_plate's (liquidtwin evaluate control's).
HORIZON = 10
CATCH_STEP, SEND_STEP = 0.1, STEP_SIZE


def _check_common(task: pb.Task, names, roles: dict, containers: tuple, controllers=("mpc",)) -> None:
    """Controller, names, distinct objects; ``roles``: {role: (name, must be a container)}."""
    if task.controller not in ("",) + tuple(controllers):
        raise EngineError(BAD_REQUEST, f"a {task.WhichOneof('kind')} task has the controller(s) "
                                       f"{', '.join(repr(c) for c in controllers)}, got {task.controller!r}")
    for role, (name, container) in roles.items():
        if name not in names:
            raise EngineError(UNKNOWN_NAME, f"{role} {name!r} is not an object of the scene ({', '.join(names)})")
        if container and name not in containers:
            raise EngineError(BAD_REQUEST, f"{role} {name!r} is not a container (its volume is not tracked)")
    used = [n for n, _ in roles.values()]
    if len(set(used)) != len(used):
        raise EngineError(BAD_REQUEST, f"the task names one object twice: {used}")


def _limit(value: float, default: float, what: str, upper: float = math.inf) -> float:
    v = value or default
    if not (math.isfinite(v) and 0 < v <= upper):
        raise EngineError(BAD_REQUEST, f"{what} must be in (0, {upper:g}] (0 = default {default:g}), got {value}")
    return float(v)


def _elapsed(eng, last_sim_t: float) -> int:
    """Model steps since the previous update (1 on the first)."""
    return 1 if last_sim_t < 0 else max(1, int(round((eng._sim_t - last_sim_t) / eng.dt)))


_POLICY = None


def shipped_policy():
    """The shipped catching policy, loaded once per process (EngineError INFEASIBLE if unusable)."""
    global _POLICY
    if _POLICY is None:
        from ..control.policy import PolicyError, load_policy
        try:
            _POLICY = load_policy()[0]
        except (PolicyError, OSError) as e:
            raise EngineError(INFEASIBLE, f"catch controller 'policy': {e}") from e
    return _POLICY


def _control(obj: str, pose_next: np.ndarray, point: np.ndarray, linear, angular, *, achieved: float,
             remaining: float, done: bool, controller: str = "mpc") -> pb.Control:
    return pb.Control(object=obj, achieved_ml=achieved, remaining_ml=max(remaining, 0.0), done=done,
                      controller=controller, axis_point_m=[float(a) for a in point], pose=[float(a) for a in pose_next],
                      linear_velocity_m_s=[float(a) for a in linear], angular_velocity_rad_s=[float(a) for a in angular])


class CatchTask:
    """``Task.catch_stream`` on a session (module doc). Build with :meth:`create`."""

    def __init__(self, task: pb.Task, eng, max_speed: float, range_m: float, x0: float, base_ml: float,
                 src_ml0: float):
        c = task.catch_stream
        names = eng.object_names
        self.task, self.max_speed, self.range_m, self.x0 = task, max_speed, range_m, float(x0)
        self.base_ml, self.src_ml0 = float(base_ml), float(src_ml0)
        self.src, self.dst = names.index(c.source), names.index(c.catcher)
        objs = eng._scene.objects
        self.src_obj, self.dst_obj = objs[self.src], objs[self.dst]
        pose = eng._frame_poses[self.dst]
        self.ctrl = CatchMPC(eng._model, slide_space(np.repeat(eng._frame_poses[None], HORIZON, 0), self.dst, x0,
                                                     range_m, max_speed), horizon=HORIZON, step_size=CATCH_STEP)
        self.policy = shipped_policy() if task.controller == "policy" else None
        self.prev = None                             # (sim t, (7,) source pose) at the previous update
        self.last_sim_t, self.control_frame = -1.0, -1
        self.command = (np.asarray(pose, float).copy(), 0.0, False)    # (pose next frame, speed m/s, done)

    @classmethod
    def create(cls, task: pb.Task, eng, *, state: dict | None = None) -> "CatchTask":
        c = task.catch_stream
        if state is None:
            _check_common(task, eng.object_names, {"catch source": (c.source, True), "catcher": (c.catcher, True)},
                          eng.container_names, controllers=("mpc", "policy"))
            max_speed = _limit(c.max_speed_m_s, MAX_SPEED, "max_speed_m_s")
            range_m = _limit(c.range_m, RANGE, "range_m")
            vols = eng.volumes()
            if vols[c.source] <= 0:
                raise EngineError(INFEASIBLE, f"catch source {c.source!r} holds no liquid: nothing will fall")
            x0 = float(eng._frame_poses[eng.object_names.index(c.catcher)][0])
            return cls(task, eng, max_speed, range_m, x0, vols[c.catcher], vols[c.source])
        d = state["task_state"]
        out = cls(task, eng, d["max_speed"], d["range_m"], d["x0"], d["base_ml"], d["src_ml0"])
        out.ctrl.load_state_dict(d["mpc"])
        out.prev = None if not d["has_prev"] else (float(d["prev_t"]), d["prev_pose"].numpy().astype(np.float64))
        out.last_sim_t, out.control_frame = float(d["last_sim_t"]), int(d["control_frame"])
        out.command = (d["command_pose"].numpy().astype(np.float64), float(d["command_speed"]), bool(d["done"]))
        return out

    def parts(self, eng) -> CatchParts:
        """The scene as the controller sees it now: the source extrapolated from its last two
        updates' poses, everything else where it is."""
        now_t, now = eng._sim_t, eng._frame_poses.copy()
        prev = self.prev

        def poses_at(t: float) -> np.ndarray:
            out = now.copy()
            if prev is not None and now_t > prev[0]:
                out[self.src] = extrapolate_pose(prev[1], now[self.src], (t - now_t) / (now_t - prev[0]))
            return out

        return CatchParts(self.src, self.src_obj, self.dst, self.dst_obj, now[self.dst].copy(), poses_at)

    def control(self, eng) -> pb.Control:
        vols = eng.volumes()
        achieved = vols[self.task.catch_stream.catcher] - self.base_ml
        if self.control_frame != eng._frames:
            self.command = self._update(eng)
            self.control_frame = eng._frames
        pose_next, speed, done = self.command
        point = eng._frame_poses[self.dst][:3]
        return _control(self.task.catch_stream.catcher, pose_next, point, [speed, 0.0, 0.0], [0.0, 0.0, 0.0],
                        achieved=achieved, remaining=vols[self.task.catch_stream.source], done=done,
                        controller=self.task.controller or "mpc")

    def _update(self, eng):
        elapsed = _elapsed(eng, self.last_sim_t)
        parts = self.parts(eng)
        t = eng._sim_t
        if self.policy is not None:
            return self._policy_update(eng, parts, elapsed)
        base = np.stack([parts.poses_at(t + (i + 1) * eng.dt) for i in range(HORIZON)])
        space = slide_space(base, self.dst, self.x0, self.range_m, self.max_speed)
        x = float(eng._frame_poses[self.dst][0])
        self.ctrl.mpc.model = eng._model              # the session's model now (a loaded extension changes it)
        with torch.enable_grad():                      # the engine runs without gradients
            loss = self.ctrl.loss(parts, eng._state, t, x, elapsed)
            u = float(self.ctrl.update(eng._state, torch.tensor([x], dtype=torch.float64), space, loss, elapsed)[0])
        return self._command(eng, x, u, elapsed, lambda: loss)

    def _policy_update(self, eng, parts, elapsed: int):
        """The learned policy's velocity from the session's particles, held until the next frame."""
        x = float(eng._frame_poses[self.dst][0])
        u = min(max(self.policy.control_at(eng._state.x, eng._frame_poses[self.dst]), -self.max_speed), self.max_speed)
        return self._command(eng, x, u, elapsed, lambda: CatchLoss(parts, eng._model, eng._state, x))

    def _command(self, eng, x: float, u: float, elapsed: int, loss):
        """(pose at the next frame, speed, done) for velocity ``u`` from ``x``; done: the source
        (next to) empty and, by ``loss()`` (asked only then), nothing falling."""
        self.prev, self.last_sim_t = (eng._sim_t, eng._frame_poses[self.src].copy()), eng._sim_t
        pose = eng._frame_poses[self.dst].copy()
        pose[0] = min(max(x + u * elapsed * eng.dt, self.x0 - self.range_m), self.x0 + self.range_m)
        in_src = float(held(eng._model, eng._state, self.src, self.src_obj)[0].sum()) * eng._ml_per_particle
        return pose, u, bool(in_src < FALLING_MIN * self.src_ml0 and loss().landing(eng._state) is None)

    def state_dict(self) -> dict:
        pose, speed, done = self.command
        return {"task": task_to_str(self.task), "task_base": self.base_ml, "control_frame": int(self.control_frame),
                "pid": {}, "task_state": {
                    "max_speed": self.max_speed, "range_m": self.range_m, "x0": self.x0, "base_ml": self.base_ml,
                    "src_ml0": self.src_ml0, "mpc": self.ctrl.state_dict(), "has_prev": self.prev is not None,
                    "prev_t": float(self.prev[0]) if self.prev else 0.0,
                    "prev_pose": torch.as_tensor(self.prev[1] if self.prev else np.zeros(7)),
                    "last_sim_t": float(self.last_sim_t), "control_frame": int(self.control_frame),
                    "command_pose": torch.as_tensor(pose), "command_speed": float(speed), "done": bool(done)}}


class SendTask:
    """``Task.send`` on a session (module doc). Build with :meth:`create`."""

    def __init__(self, task: pb.Task, eng, max_angle: float, max_rate: float, rest: np.ndarray, base_ml: float,
                 ids: torch.Tensor, held0: int):
        s = task.send
        names = eng.object_names
        self.task, self.max_angle, self.max_rate = task, float(max_angle), float(max_rate)
        self.rest, self.base_ml, self.ids, self.held0 = np.asarray(rest, float), float(base_ml), ids, int(held0)
        self.obj, self.dst = names.index(s.object), names.index(s.target)
        self.aim = aim_point(eng._frame_poses[self.dst], eng._scene.objects[self.dst])
        # how fast the loss asks to send the liquid: by the amount on the object at the start
        self.lookahead = lookahead_for(self.held0 * eng._model.particle_volume * 1e6)
        self.mpc = MPC(eng._model, self._space(eng), None, horizon=HORIZON, step_size=SEND_STEP)
        self.last_sim_t, self.control_frame = -1.0, -1
        self.command = (np.asarray(eng._frame_poses[self.obj], float).copy(), np.zeros(3), False)

    @classmethod
    def create(cls, task: pb.Task, eng, *, state: dict | None = None) -> "SendTask":
        s = task.send
        if state is None:
            _check_common(task, eng.object_names, {"send object": (s.object, True), "send target": (s.target, True)},
                          eng.container_names)
            max_angle = _limit(s.max_angle_rad, MAX_TILT, "max_angle_rad", upper=math.pi / 2)
            max_rate = _limit(s.max_rate_rad_s, MAX_RATE, "max_rate_rad_s")
            k = eng.object_names.index(s.object)
            obj = eng._scene.objects[k]
            on = held(eng._model, eng._state, k, obj)[0]
            if not bool(on.any()):
                raise EngineError(INFEASIBLE, f"send object {s.object!r} holds no liquid to send")
            ids = eng._state.ids[torch.as_tensor(on)].clone()
            return cls(task, eng, max_angle, max_rate, eng._frame_poses[k], eng.volumes()[s.target], ids,
                       int(on.sum()))
        d = state["task_state"]
        out = cls(task, eng, d["max_angle"], d["max_rate"], d["rest"].numpy().astype(np.float64), d["base_ml"],
                  d["ids"].clone(), d["held0"])
        out.mpc.plan = d["plan"].clone()
        out.last_sim_t, out.control_frame = float(d["last_sim_t"]), int(d["control_frame"])
        out.command = (d["command_pose"].numpy().astype(np.float64), d["command_omega"].numpy().astype(np.float64),
                       bool(d["done"]))
        return out

    def _space(self, eng):
        return tilt2_space(eng._frame_poses, self.obj, self.rest, self.max_angle, self.max_rate)

    def control(self, eng) -> pb.Control:
        achieved = eng.volumes()[self.task.send.target] - self.base_ml
        if self.control_frame != eng._frames:
            self.command = self._update(eng)
            self.control_frame = eng._frames
        pose_next, omega, done = self.command
        remaining = eng.volumes()[self.task.send.object]
        return _control(self.task.send.object, pose_next, eng._frame_poses[self.obj][:3], [0.0, 0.0, 0.0], omega,
                        achieved=achieved, remaining=remaining, done=done)

    def _update(self, eng):
        elapsed = _elapsed(eng, self.last_sim_t)
        self.mpc.skip(elapsed)                          # the plan's first elapsed-1 steps are past
        space = self._space(eng)
        q = torch.as_tensor(tilt2_of(eng._frame_poses[self.obj], self.rest), dtype=torch.float64)
        self.mpc.model, self.mpc.space = eng._model, space
        # the rates change as fast per second as at one update a step (smaller steps for slower sends)
        self.mpc.step_size = step_for(self.lookahead, SEND_STEP) * elapsed
        self.mpc.loss = send_loss(self.aim.to(eng._state.x.dtype), UPRIGHT_WEIGHT, self.lookahead,
                                  ids=self._live(eng))
        with torch.enable_grad():
            u = self.mpc.update(eng._state, q)[0]
        self.last_sim_t = eng._sim_t
        q_next = torch.clamp(q + u * elapsed * eng.dt, space.lower, space.upper)
        pose_next = space.to_pose(q_next[None])[0].numpy()
        # ω of R = Rx(a)·Rz(b)·R_rest: ȧ about x, ḃ about Rx(a)'s z
        a = float(q[0])
        omega = float(u[0]) * np.array([1.0, 0.0, 0.0]) + float(u[1]) * np.array([0.0, -math.sin(a), math.cos(a)])
        k = self.obj
        left = int(held(eng._model, eng._state, k, eng._scene.objects[k])[0].sum())
        done = left < FALLING_MIN * self.held0 and float(q.abs().max()) < math.radians(2.0)
        return pose_next, omega, bool(done)

    def _live(self, eng) -> torch.Tensor:
        """The task's particles still in the session (culled ones dropped)."""
        return self.ids[torch.isin(self.ids, eng._state.ids)]

    def state_dict(self) -> dict:
        pose, omega, done = self.command
        return {"task": task_to_str(self.task), "task_base": self.base_ml, "control_frame": int(self.control_frame),
                "pid": {}, "task_state": {
                    "max_angle": self.max_angle, "max_rate": self.max_rate, "rest": torch.as_tensor(self.rest),
                    "base_ml": self.base_ml, "ids": self.ids.clone(), "held0": self.held0,
                    "plan": self.mpc.plan.clone(), "last_sim_t": float(self.last_sim_t),
                    "control_frame": int(self.control_frame), "command_pose": torch.as_tensor(pose),
                    "command_omega": torch.as_tensor(omega), "done": bool(done)}}

