"""The thesis's *pouring* task (§8.3.3): rotate a cup about its lip to pour a given amount
into the bowl below, by MPC through SPNets.

Control: the cup's angular velocity about its own z axis (rad/s; the angle turns the opening
towards −x, the lip staying where it is). Piecewise loss, as the thesis: until the switch,
the mean distance of the particles still in the cup to the lip, each a short lookahead
ahead at its velocity (below; the cup "finds" the tilt that makes them flow); then the
squared tilt angle (back upright).

When to switch: the thesis switches once the asked amount has left the cup, so everything
that still flows while the cup turns back is extra. With ``anticipate`` (default) the model
predicts it: every ``CHECK_EVERY`` steps (every update once a prediction reached ``NEAR`` of
the ask; from a tilt of ``MIN_CHECK_TILT`` on) a no-gradient rollout keeps the planned
control until the next update, then turns the cup back at the rate limit and lets the stream
land. Once that reaches the ask, a second rollout turns back now, and the controller switches
now or at the next update, whichever lands closer to the ask (an update is one model step
here, one camera frame in a session: several steps). The return is that same max-rate
manoeuvre (what was predicted is what is done).

The pull to the lip looks ``lookahead_s`` ahead (default ``LOOKAHEAD_S`` = 0.1 s; 0: the
thesis's loss): each particle counts at x + lookahead·v. Without it the full-size cup stalled:
the cup turns about the lip, so turning it moves no held particle towards the lip; only the
flow gravity starts does, and within a 10-step horizon (83 ms) that shows in velocities
more than in positions. The gradient with respect to the plan's last 4–5 controls (their
immediate push on the liquid) then points back, the first 5 forward, and the MPC's step per
control (eq. 8.5: for a one-dimensional control, its sign) cancels: the full-size cup with
300 ml hovered at 35–45° for 6 s while ~10 ml/s left it (stop 56: 75 ml switched at 8.0 s;
275 ml missed by 8.45 ml in 10 s). With the lookahead 7 of the 10 gradients point forward (both
measured at 38° and 42° after a 1 s and a 0.5 s hold; without the lookahead autograd agrees
there with central differences in the sign of every component, and within ~10 % on the
large ones); measured results in the README.

``approach_rate`` (off by default) caps the forward tilt rate from ``MIN_CHECK_TILT`` on, so
the cup reaches the angle where liquid starts to flow slowly: at the full rate the liquid
lags and then leaves in one surge (on the quick cup, 60 ml, ~21 ml in 0.3 s at 2 rad/s), most
of which misses the bowl. The return keeps the full rate. The slow approach stays near the
ask longer, and near the ask every update runs a drain prediction, so it costs time.
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
from .mpc import MPC, ControlError, ControlSpace, by_ids

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
#: The pull to the lip scores each particle LOOKAHEAD_S ahead at its velocity (module doc).
LOOKAHEAD_S = 0.1


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


def check_approach_rate(rate: float | None) -> float | None:
    """``rate`` as a float (None: no cap); ControlError unless a positive number of rad/s."""
    if rate is not None and not (math.isfinite(rate) and rate > 0):
        raise ControlError(f"approach_rate must be a positive number of rad/s, got {rate}")
    return None if rate is None else float(rate)


def check_lookahead(s: float) -> float:
    """``s`` as a float; ControlError unless a finite number of seconds >= 0."""
    if not (math.isfinite(s) and s >= 0):
        raise ControlError(f"lookahead must be a number of seconds >= 0, got {s}")
    return float(s)


def _return_rate(q: torch.Tensor, dt: float, max_rate) -> torch.Tensor:
    """The return manoeuvre's control: back towards upright at the rate limit, no overshoot."""
    max_rate = torch.as_tensor(max_rate, dtype=q.dtype)
    return -torch.minimum(torch.maximum(q / dt, -max_rate), max_rate)


@torch.no_grad()
def predict_landed(model, state, q, space, dst: int, dst_obj, ml_per_particle: float, hold=None) -> float:
    """ml the target holds after turning back (max-rate return, then ``LAND_S`` s): now, or
    with ``hold`` = (u (1,), k) after k more steps at the control u (the next update's turn)."""
    s = state
    for _ in range(hold[1] if hold is not None else 0):
        q = space.positions(q, hold[0][None], model.dt)[0]
        s = step(model, s, space.poses(q[None])[0].to(s.x))
    rate = float(space.max_rate[0])
    steps = int(math.ceil(abs(float(q)) / (rate * model.dt))) + int(round(LAND_S / model.dt))
    for _ in range(steps):
        q = space.positions(q, _return_rate(q, model.dt, space.max_rate)[None], model.dt)[0]
        s = step(model, s, space.poses(q[None])[0].to(s.x))
    return float(held(model, s, dst, dst_obj)[0].sum()) * ml_per_particle


class PourMPC:
    """One pour task's MPC controller (module doc), driven one control step at a time, by
    :func:`run_pour` (a simulated cup) or by a service session (the robot's cup).

    ``update(state, q, space, lip, elapsed)`` → the control (rad/s, (1,)) to execute from the
    tracked ``state`` with the cup at tilt ``q`` ((1,) rad); ``space`` maps tilts to scene
    poses from *now* and ``lip`` is where the pour lip is now (a session's poses change every
    frame); ``elapsed``: model steps since the previous update (a session updates once per
    frame: the plan moves on by that many steps). ``done`` turns True at the switch: from
    then on the cup returns upright at the rate limit (``anticipate``) or by MPC on the
    squared angle (the thesis). Amounts are counted from what the target holds in ``state``
    when the controller is made (``base_ml``)."""

    def __init__(self, model, space: ControlSpace, lip: torch.Tensor, src: int, dst: int, src_obj, dst_obj,
                 target_ml: float, ml_per_particle: float, *, state,
                 horizon: int = 10, step_size: float = 0.5, anticipate: bool = True,
                 approach_rate: float | None = None, lookahead_s: float = LOOKAHEAD_S):
        self.approach_rate = check_approach_rate(approach_rate)
        self.lookahead_s = check_lookahead(lookahead_s)
        self.model, self.src, self.dst, self.src_obj, self.dst_obj = model, src, dst, src_obj, dst_obj
        self.target_ml, self.ml, self.anticipate = float(target_ml), float(ml_per_particle), bool(anticipate)
        self.base_ml = float(held(model, state, dst, dst_obj)[0].sum()) * self.ml
        self.lip = torch.as_tensor(lip).to(state.x)
        in_cup = held(model, state, src, src_obj)[0]
        self.cup0 = int(in_cup.sum())
        self.done, self.predicted, self.updates, self.steps = False, 0.0, 0, 0     # steps: model steps run
        self.ids = state.ids[torch.as_tensor(in_cup)]
        self.mpc = MPC(model, space, self._loss, horizon=horizon, step_size=step_size)

    def _loss(self, s, k, q):
        if not self.done:
            x, v = by_ids(s, self.ids)
            return (x + self.lookahead_s * v - self.lip).norm(dim=1).mean()
        return (q ** 2).sum()

    def update(self, state, q: torch.Tensor, space: ControlSpace | None = None, lip=None,
               elapsed: int = 1) -> torch.Tensor:
        if space is not None:
            self.mpc.space = space
        if lip is not None:
            self.lip = torch.as_tensor(lip).to(state.x)
        self.mpc.skip(elapsed)               # the plan's first elapsed-1 steps are past
        space = self.mpc.space
        prev = self.steps
        if self.updates:
            self.steps += int(elapsed)
        self.updates += 1
        if self.done:
            return self.mpc.update(state, q)[0] if not self.anticipate else \
                _return_rate(q, self.model.dt, space.max_rate)
        held_now = held(self.model, state, self.src, self.src_obj)[0]
        if not self.anticipate:                       # the thesis: once the ask has left the cup
            if (self.cup0 - int(held_now.sum())) * self.ml >= self.target_ml:
                self.done = True
                self.mpc.plan = torch.zeros_like(self.mpc.plan)
            else:
                self.ids = state.ids[torch.as_tensor(held_now)]
            return self.mpc.update(state, q)[0]
        self.ids = state.ids[torch.as_tensor(held_now)]
        u = self.mpc.update(state, q)[0]              # what runs until the next update, unless we switch
        if self.approach_rate is not None and float(q[0]) > MIN_CHECK_TILT:
            u = torch.clamp(u, max=self.approach_rate)
        near = self.predicted >= NEAR * self.target_ml              # close: check every update
        due = self.updates == 1 or self.steps // CHECK_EVERY > prev // CHECK_EVERY
        if float(q[0]) > MIN_CHECK_TILT and (near or due):
            ask = lambda hold=None: predict_landed(self.model, state, q[0], space, self.dst,  # noqa: E731
                                                   self.dst_obj, self.ml, hold) - self.base_ml
            self.predicted = ask((u, int(elapsed)))                 # turning back at the next update
            # now or next: whichever lands closer to the ask
            if self.predicted >= self.target_ml and self.predicted - self.target_ml > self.target_ml - ask():
                self.done = True
                self.mpc.plan = torch.zeros_like(self.mpc.plan)
                return _return_rate(q, self.model.dt, space.max_rate)
        return u

    def state_dict(self) -> dict:
        """What changes (tensors and plain numbers; torch.load(weights_only=True))."""
        return {"done": self.done, "predicted": float(self.predicted), "updates": int(self.updates),
                "steps": int(self.steps),
                "base_ml": self.base_ml, "cup0": self.cup0, "ids": self.ids.clone(), "plan": self.mpc.plan.clone()}

    def load_state_dict(self, d: dict) -> None:
        self.done, self.predicted, self.updates = bool(d["done"]), float(d["predicted"]), int(d["updates"])
        self.base_ml, self.cup0 = float(d["base_ml"]), int(d["cup0"])
        self.steps = int(d["steps"])
        self.ids, self.mpc.plan = d["ids"].clone(), d["plan"].clone()


def run_pour(setup, model, state, target_ml: float, ml_per_particle: float, *, max_seconds: float = 6.0,
             horizon: int = 10, step_size: float = 0.5, anticipate: bool = True, progress: bool = False,
             approach_rate: float | None = None, lookahead_s: float = LOOKAHEAD_S, on_step=None) -> PourRun:
    """Pour ``target_ml`` from the scene's source into its target from ``state`` (``approach_rate``:
    :class:`PourMPC`). ``on_step(i, state, q, controller)`` is called after every step."""
    src, dst = setup.index("source"), setup.index("target")
    src_obj, dst_obj = setup.objects[src].model, setup.objects[dst].model
    n = int(state.x.shape[0])
    have = float(held(model, state, src, src_obj)[0].sum()) * ml_per_particle
    if not (math.isfinite(target_ml) and 0 < target_ml < have):
        raise ControlError(f"cannot pour {target_ml} ml: the cup holds {have:.1f} ml")
    space, lip = lip_space(setup)
    ctrl = PourMPC(model, space, lip, src, dst, src_obj, dst_obj, target_ml, ml_per_particle, state=state,
                   horizon=horizon, step_size=step_size, anticipate=anticipate, approach_rate=approach_rate,
                   lookahead_s=lookahead_s)
    q = torch.zeros(1, dtype=torch.float64)
    angles, switched = [], None
    steps = int(round(max_seconds / model.dt))
    t0 = time.perf_counter()
    bar = tqdm(range(steps), desc=f"pour {target_ml:g} ml", unit="step", disable=not progress, leave=False)
    for i in bar:
        if ctrl.done and abs(float(q)) < UPRIGHT:
            held_now = held(model, state, src, src_obj)[0]
            in_dst = held(model, state, dst, dst_obj)[0]
            falling = ~(held_now | in_dst) & (state.x[:, 1].detach().numpy() > 0.005)
            if not falling.any():
                break
        was_done = ctrl.done
        u = ctrl.update(state, q)
        if ctrl.done and not was_done:
            switched = i * model.dt
        q = space.positions(q, u[None], model.dt)[0]
        with torch.no_grad():
            state = step(model, state, space.poses(q[None])[0].to(state.x.dtype))
        angles.append(math.degrees(float(q)))
        if on_step is not None:
            on_step(i, state, q, ctrl)
    wall = time.perf_counter() - t0
    in_src = held(model, state, src, src_obj)[0]
    in_dst = held(model, state, dst, dst_obj)[0]
    return PourRun(target_ml, float(in_dst.sum()) * ml_per_particle, (n - int(in_src.sum())) * ml_per_particle,
                   float((~(in_src | in_dst)).sum()) * ml_per_particle, np.asarray(angles), switched,
                   len(angles) * model.dt, wall / max(len(angles), 1))
