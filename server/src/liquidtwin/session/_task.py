"""A session's task: checking a pour request against the scene and driving its controller."""

from __future__ import annotations

import math

from google.protobuf import json_format
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..control import PourPID
from .errors import BAD_REQUEST, INFEASIBLE, UNKNOWN_NAME, EngineError

#: Limits used when a task leaves them at 0: tilt up to 135° at up to 1 rad/s.
DEFAULT_MAX_ANGLE = math.radians(135.0)
DEFAULT_MAX_RATE = 1.0


def make_controller(task: pb.Task, names, containers, volumes: dict, capacities: dict,
                    source_tilt: float) -> PourPID:
    """The PourPID for a pour task; EngineError (UNKNOWN_NAME, BAD_REQUEST, INFEASIBLE) if the
    task cannot be done in this scene now. ``volumes``: ml per container now;
    ``capacities``: ml per container to the rim; ``source_tilt``: the source's tilt, rad."""
    if task.controller not in ("", "pid"):
        if task.controller == "mpc":
            raise EngineError(INFEASIBLE, "controller 'mpc' is not available in this version; use 'pid'")
        raise EngineError(BAD_REQUEST, f"unknown controller {task.controller!r}; use 'pid'")
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
    return PourPID(p.volume_ml, max_angle, max_rate, angle=min(source_tilt, max_angle))


def control_message(task: pb.Task, pid: PourPID, poured_ml: float) -> pb.Control:
    """The Control for the controller's last update (header left to the service)."""
    remaining = max(pid.target_ml - poured_ml, 0.0)
    return pb.Control(object=task.pour.source, tilt_angle_rad=pid.angle, tilt_rate_rad_s=pid.rate,
                      achieved_ml=poured_ml, remaining_ml=remaining, done=pid.done,
                      controller=task.controller or "pid")


def task_to_str(task: pb.Task) -> str:
    return json_format.MessageToJson(task)


def task_from_str(text: str) -> pb.Task:
    return json_format.Parse(text, pb.Task())
