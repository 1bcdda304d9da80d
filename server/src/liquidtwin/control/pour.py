"""The thesis's *pouring* task (§8.3.3): rotate a cup about its lip to pour a given amount
into the bowl below, by MPC through SPNets.

Control: the cup's angular velocity about its own z axis (rad/s; the angle turns the opening
towards −x, the lip staying where it is). Piecewise loss, as the thesis: until the switch,
the mean distance of the particles still in the cup to the lip (the cup "finds" the tilt
that makes them flow); then the squared tilt angle (back upright).

When to switch: the thesis switches once the asked amount has left the cup, so everything
that still flows while the cup turns back is extra. With ``anticipate`` (default) the model
predicts it: every ``CHECK_EVERY`` steps (every step once a prediction reached ``NEAR`` of
the ask; from a tilt of ``MIN_CHECK_TILT`` on) a no-gradient rollout turns the cup back at the rate limit and lets the stream land; the
switch comes at the first check whose predicted amount in the target reaches the ask. The
return is then that same max-rate manoeuvre (what was predicted is what is done).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from tqdm.auto import tqdm

from ..scenes.liquid_level import held
from ..sim import step
from .mpc import MPC, ControlError, ControlSpace

#: Tilt limits (rad) and rate limit (rad/s) of the cup.
MIN_TILT, MAX_TILT = math.radians(-10.0), math.radians(150.0)
MAX_RATE = 2.0
#: Done when the cup is back within this angle and nothing is still falling.
UPRIGHT = math.radians(3.0)
#: Steps between drain predictions, and how long a prediction lets the stream land, s.
CHECK_EVERY = 4
NEAR = 0.7              # … and every step once a prediction reached this share of the ask
MIN_CHECK_TILT = math.radians(20.0)
LAND_S = 1.0


def lip_space(setup, name: str = "source") -> tuple[ControlSpace, torch.Tensor]:
    """(ControlSpace of the cup's tilt about its lip, the lip's world position (3,))."""
    k = setup.index(name)
    base = torch.as_tensor(setup.poses_at(0.0), dtype=torch.float64)
    motion = setup.objects[k].motion
    lip_local = torch.as_tensor(motion.pivot, dtype=torch.float64)
    lip_world = torch.as_tensor(motion.path(0.0), dtype=torch.float64)

    def to_pose(q):                       # rotation about object z through the lip
        a = q[:, 0]
        c, s = torch.cos(a), torch.sin(a)
        rl = torch.stack([c * lip_local[0] - s * lip_local[1], s * lip_local[0] + c * lip_local[1],
                          lip_local[2].expand_as(a)], dim=1)
        quat = torch.stack([torch.zeros_like(a), torch.zeros_like(a), torch.sin(a / 2), torch.cos(a / 2)], dim=1)
        return torch.cat([lip_world.to(q.dtype) - rl, quat], dim=1)

    space = ControlSpace(base, k, to_pose, torch.tensor([MIN_TILT], dtype=torch.float64),
                         torch.tensor([MAX_TILT], dtype=torch.float64), torch.tensor([MAX_RATE], dtype=torch.float64))
    return space, lip_world


@dataclass
class PourRun:
    target_ml: float
    poured_ml: float        # in the target container at the end
    left_ml: float          # what left the cup
    spilled_ml: float       # neither in the cup nor in the target
    angles_deg: np.ndarray  # (steps,)
    switched_s: float | None
    seconds: float
    update_s: float


def _return_rate(q: torch.Tensor, dt: float) -> torch.Tensor:
    """The return manoeuvre's control: back towards upright at the rate limit, no overshoot."""
    return -torch.clamp(q / dt, -MAX_RATE, MAX_RATE)


@torch.no_grad()
def predict_landed(model, state, q, space, dst: int, dst_obj, ml_per_particle: float) -> float:
    """ml the target holds after turning back now (max-rate return, then ``LAND_S`` s)."""
    s = state
    steps = int(math.ceil(abs(float(q)) / (MAX_RATE * model.dt))) + int(round(LAND_S / model.dt))
    for _ in range(steps):
        q = space.positions(q, _return_rate(q, model.dt)[None], model.dt)[0]
        s = step(model, s, space.poses(q[None])[0].to(s.x.dtype))
    return float(held(model, s, dst, dst_obj)[0].sum()) * ml_per_particle


def run_pour(setup, model, state, target_ml: float, ml_per_particle: float, *, max_seconds: float = 6.0,
             horizon: int = 10, step_size: float = 0.5, anticipate: bool = True, progress: bool = False) -> PourRun:
    """Pour ``target_ml`` from the scene's source into its target from ``state``."""
    src, dst = setup.index("source"), setup.index("target")
    src_obj, dst_obj = setup.objects[src].model, setup.objects[dst].model
    n = int(state.x.shape[0])
    in_cup = held(model, state, src, src_obj)[0]
    have = float(in_cup.sum()) * ml_per_particle
    if not (math.isfinite(target_ml) and 0 < target_ml < have):
        raise ControlError(f"cannot pour {target_ml} ml: the cup holds {have:.1f} ml")
    space, lip = lip_space(setup)
    lip = lip.to(state.x.dtype)
    phase = {"pour": True, "ids": torch.as_tensor(np.flatnonzero(in_cup))}

    def loss(s, k, q):
        if phase["pour"]:
            x, _ = s.by_id()
            return (x[phase["ids"]] - lip).norm(dim=1).mean()
        return (q ** 2).sum()

    mpc = MPC(model, space, loss, horizon=horizon, step_size=step_size)
    q = torch.zeros(1, dtype=torch.float64)
    angles, switched = [], None
    steps = int(round(max_seconds / model.dt))
    t0 = time.perf_counter()
    bar = tqdm(range(steps), desc=f"pour {target_ml:g} ml", unit="step", disable=not progress, leave=False)
    for i in bar:
        held_now = held(model, state, src, src_obj)[0]
        left = (n - int(held_now.sum())) * ml_per_particle
        if phase["pour"]:
            if anticipate:
                near = phase.get("predicted", 0.0) >= NEAR * target_ml     # close: check every step
                if float(q) > MIN_CHECK_TILT and (near or i % CHECK_EVERY == 0):
                    phase["predicted"] = predict_landed(model, state, q, space, dst, dst_obj, ml_per_particle)
                done = phase.get("predicted", 0.0) >= target_ml
            else:
                done = left >= target_ml
            if done:
                phase["pour"], switched = False, i * model.dt
                mpc.plan = torch.zeros_like(mpc.plan)
            else:
                phase["ids"] = torch.as_tensor(np.flatnonzero(held_now))
        if not phase["pour"] and abs(float(q)) < UPRIGHT:
            in_dst = held(model, state, dst, dst_obj)[0]
            falling = ~(held_now | in_dst) & (state.x[:, 1].detach().numpy() > 0.005)
            if not falling.any():
                break
        if phase["pour"] or not anticipate:
            u, _ = mpc.update(state, q)
        else:
            u = _return_rate(q, model.dt)
        q = space.positions(q, u[None], model.dt)[0]
        with torch.no_grad():
            state = step(model, state, space.poses(q[None])[0].to(state.x.dtype))
        angles.append(math.degrees(float(q)))
    wall = time.perf_counter() - t0
    in_src = held(model, state, src, src_obj)[0]
    in_dst = held(model, state, dst, dst_obj)[0]
    return PourRun(target_ml, float(in_dst.sum()) * ml_per_particle, (n - int(in_src.sum())) * ml_per_particle,
                   float((~(in_src | in_dst)).sum()) * ml_per_particle, np.asarray(angles), switched,
                   len(angles) * model.dt, wall / max(len(angles), 1))
