"""The thesis's *catching* task (§8.3.3): slide a cup along x under the stream of a source
that pours while it moves, so the cup catches the liquid.

Scene: the catalogue's ``catching`` scene (a cup pouring from 32 cm, the "hold" pour), with
the source's lip moving along x during the pour (:data:`SOURCE_MOTIONS`: 8 motions, pouring
towards −x or +x, the lip drifting at one of four speeds) and the catcher starting right
below the lip, a stream's reach (8.5 cm) away from where the liquid first lands.

Control: the catcher's velocity along world x (m/s; ±``MAX_SPEED``, within ``RANGE`` of its
start). The source's motion is the robot's own script, so the rollout knows it. Loss: the
mean horizontal distance between where each falling particle will land (ballistically,
where it crosses the catcher's rim height) and the catcher's axis, over the particles that
left the source and are still above that height (not counting those over the catcher's
opening within ``SPLASH_H`` of its rim: its own splashes). While nothing falls (before the pour,
after it: less than ``FALLING_MIN`` of the liquid) the loss is the distance to where the
first liquid will land — predicted by a no-gradient rollout of the model ``LOOKAHEAD``
steps ahead under the source's script (:func:`first_landing`) — or, when the model predicts
nothing falling that soon, the distance from where the catcher is: it holds still. (All
three terms are distances in m, so a policy trained on the sum weighs them alike; the MPC
normalises its step and sees only their directions.)

Why the lookahead: the stream starts abruptly, up to 16 cm from a catcher that waited
below the lip, and most of the liquid falls in the next half second; at 0.5 m/s the catcher
needs a third of a second to get there. A 10-step (83 ms) MPC horizon sees the stream only
when it has started (measured: 67–71 % caught on the two fastest-receding motions, the
catcher arriving when half the liquid had fallen).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from tqdm.auto import tqdm

from ..scenes import motions as mo
from ..scenes.liquid_level import held
from ..sim import step
from .mpc import MPC, ControlError, ControlSpace, by_ids

#: (pour direction: −1 towards −x / +1 towards +x, lip drift along x in m/s) of the 8 motions.
SOURCE_MOTIONS = tuple((d, v) for d in (-1, 1) for v in (-0.06, -0.02, 0.02, 0.06))
MAX_SPEED = 0.5
RANGE = 0.3
G = 9.81
#: Below this share of the liquid falling, the catcher holds still: the loss's gradient is
#: the mean direction to each landing point (it seeks their median), so a few drips or
#: splashes would otherwise steer it as hard as the stream (measured: after the stream the
#: catcher wandered to its range limit, spilling what it held).
FALLING_MIN = 0.02
#: Particles over the catcher's opening and less than this above its rim (m) are its own
#: business: about to land in it, or splashing out of it and back. Counting them, the
#: catcher chased its own splashes after the stream (motion 1: 5 cm at up to 0.5 m/s with
#: the catch sloshing in it, 10 % lost).
SPLASH_H = 0.05
#: Steps the first-landing prediction looks ahead (0.4 s at 120 Hz) and how often (steps) it
#: is re-run while nothing falls.
LOOKAHEAD, LOOKAHEAD_EVERY = 48, 6


def catching_setup(motion: int, quick: bool = True, seed: int = 0):
    """The catching scene with source motion ``motion`` (index into :data:`SOURCE_MOTIONS`)."""
    from ..generate.catalog import build_setup
    if not 0 <= motion < len(SOURCE_MOTIONS):
        raise ControlError(f"catching has source motions 0-{len(SOURCE_MOTIONS) - 1}, got {motion}")
    base = build_setup("catching", np.random.default_rng(seed), quick=quick)
    direction, drift = SOURCE_MOTIONS[motion]
    pour = base.objects[base.index("source")].motion
    lip = np.asarray(pour.path(0.0), float)
    start, end = pour.angle.times[1], pour.end                  # the tilt begins / the pour is over
    path = mo.Profile.of((0.0, lip), (start, lip), (end, lip + [drift * (end - start), 0.0, 0.0]))
    # +z tips the opening (lip on the cup's −x side) towards −x; towards +x: mirrored lip, −z.
    pivot = np.asarray(pour.pivot, float) * ([1.0, 1.0, 1.0] if direction < 0 else [-1.0, 1.0, 1.0])
    axis = (0.0, 0.0, 1.0) if direction < 0 else (0.0, 0.0, -1.0)
    motion_src = dataclasses.replace(pour, pivot=tuple(pivot), axis=axis, path=path)
    still = mo.Static(tuple(np.concatenate([[lip[0], 0.0, lip[2]], [0.0, 0.0, 0.0, 1.0]])))
    objects = tuple(dataclasses.replace(o, motion=motion_src) if o.name == "source" else
                    dataclasses.replace(o, motion=still) if o.name == "catcher" else o for o in base.objects)
    return dataclasses.replace(base, objects=objects, notes={"motion": motion, "direction": direction,
                                                             "drift_m_s": drift})


@dataclass(frozen=True, eq=False)
class CatchParts:
    """What the catching task needs of a scene: the source's and the catcher's indices and
    object models, the catcher's pose at rest (7,) (its rim height and z count), and
    ``poses_at(t)`` → (M, 7) the scene's poses at time t s (the source where it will be; the
    catcher where it rests). From a catalogue setup: :meth:`of`; a session builds its own
    from the frames it has seen (:mod:`liquidtwin.session._motion_tasks`)."""

    src: int
    src_obj: object
    dst: int
    dst_obj: object
    rest: np.ndarray
    poses_at: Callable

    @classmethod
    def of(cls, setup) -> "CatchParts":
        src, dst = setup.index("source"), setup.index("catcher")
        return cls(src, setup.objects[src].model, dst, setup.objects[dst].model,
                   np.asarray(setup.poses_at(0.0)[dst], float), setup.poses_at)


def extrapolate_pose(pose0, pose1, s: float) -> np.ndarray:
    """(7,) the pose a rigid body reaches if the motion that took it from ``pose0`` to
    ``pose1`` goes on for ``s`` more times as long, at the same twist: a screw motion (a turn
    about a fixed axis plus a slide along it; exact for a cup turning about its lip at a
    constant rate, and for a constant velocity)."""
    p0, p1 = np.asarray(pose0, float), np.asarray(pose1, float)
    q0, q1 = p0[3:] / np.linalg.norm(p0[3:]), p1[3:] / np.linalg.norm(p1[3:])
    dq = mo.quat_multiply(q1, q0 * [-1.0, -1.0, -1.0, 1.0])
    dq = dq if dq[3] >= 0 else -dq
    r = mo.quat_matrix(dq)
    d = p1[:3] - r @ p0[:3]                                  # the step maps x to r x + d
    sin_half = float(np.linalg.norm(dq[:3]))
    if sin_half < 1e-9:                                     # no turn: a constant velocity
        return np.concatenate([p1[:3] + s * d, q1])
    axis = dq[:3] / sin_half
    angle = 2.0 * np.arctan2(sin_half, dq[3])
    along = float(axis @ d)
    c = np.linalg.lstsq(np.eye(3) - r, d - along * axis, rcond=None)[0]     # a point on the screw axis
    rs = mo.quat_axis_angle(axis, s * angle)
    return np.concatenate([c + mo.quat_matrix(rs) @ (p1[:3] - c) + s * along * axis, mo.quat_multiply(rs, q1)])


def slide_space(base_poses, index: int, x0: float, range_m: float = RANGE, max_speed: float = MAX_SPEED) -> ControlSpace:
    """ControlSpace of object ``index``'s x (m, world) within ``x0 ± range_m`` at up to
    ``max_speed`` m/s, the scene otherwise at ``base_poses`` ((horizon, M, 7): one per planned
    step; the controlled object keeps its first pose's y, z and rotation)."""
    base = torch.as_tensor(np.asarray(base_poses, float), dtype=torch.float64)
    rest = base[0, index].clone()

    def to_pose(q):
        pose = rest.to(q.dtype).expand(q.shape[0], 7).clone()
        return torch.cat([q[:, :1], pose[:, 1:]], dim=1)

    t = lambda v: torch.tensor([float(v)], dtype=torch.float64)  # noqa: E731
    return ControlSpace(base, index, to_pose, t(x0 - range_m), t(x0 + range_m), t(max_speed))


def catch_space(setup, t: float, horizon: int, dt: float) -> ControlSpace:
    """ControlSpace of the catcher's x from time ``t``: the other objects at their scripted
    poses of each planned step ((horizon, M, 7) base poses)."""
    k = setup.index("catcher")
    base = np.stack([setup.poses_at(t + (i + 1) * dt) for i in range(horizon)])
    return slide_space(base, k, float(setup.objects[k].motion(0.0)[0]))


class CatchLoss:
    """The task loss of a rollout from one state (module doc): ``loss(s, k, q)`` for the MPC
    and the policy alike. ``parts``: a :class:`CatchParts` (or a catalogue setup); ``away``:
    the particles that had left the source when the rollout began; ``hold_x``: where the
    catcher was then; ``aim``: where the first liquid is predicted to land (x, m; None:
    nothing predicted)."""

    def __init__(self, parts, model, state, hold_x: float, aim: float | None = None):
        parts = parts if isinstance(parts, CatchParts) else CatchParts.of(parts)
        self.n = int(state.x.shape[0])
        self.away = state.ids[torch.as_tensor(~held(model, state, parts.src, parts.src_obj)[0])]
        self.hold_x = float(hold_x)
        self.aim = None if aim is None or not np.isfinite(aim) else float(aim)
        dst, pose = parts.dst, parts.rest
        self.dst = dst
        self.rim_y = float(pose[1]) + float(parts.dst_obj.rim_height)
        self.rest_z = float(pose[2])
        b = parts.dst_obj.cavity.bounds
        self.r_open = 0.5 * float(min(b[1, 0] - b[0, 0], b[1, 2] - b[0, 2]))

    def landing(self, s) -> tuple[torch.Tensor, torch.Tensor] | None:
        """(x, z) m where each falling particle crosses the catcher's rim height (ballistic),
        or None while (next to) nothing falls (differentiable). Not counted: particles over
        the catcher's opening less than ``SPLASH_H`` above its rim."""
        x, v = by_ids(s, self.away)
        c = s.poses[self.dst, :3].detach().to(x.dtype)
        over = (x[:, 0] - c[0]) ** 2 + (x[:, 2] - c[2]) ** 2 < self.r_open ** 2
        above = (x[:, 1] > self.rim_y) & ~(over & (x[:, 1] < self.rim_y + SPLASH_H))
        if int(above.sum()) < FALLING_MIN * self.n:
            return None
        x, v = x[above], v[above]
        t_hit = (v[:, 1] + torch.sqrt(v[:, 1] ** 2 + 2.0 * G * (x[:, 1] - self.rim_y))) / G
        return x[:, 0] + v[:, 0] * t_hit, x[:, 2] + v[:, 2] * t_hit

    def __call__(self, s, k, q):
        land = self.landing(s)
        if land is None:                                # nothing falling: go where it will land, or hold
            if self.aim is not None:
                return torch.sqrt((q[0] - self.aim) ** 2 + 1e-12)
            return torch.sqrt((q[0] - self.hold_x) ** 2 + 1e-12)
        land_x, land_z = land
        return torch.sqrt((land_x - q[0]) ** 2 + (land_z - self.rest_z) ** 2 + 1e-12).mean()


def first_landing(parts, model, state, t: float, x_catcher: float, steps: int = LOOKAHEAD) -> float:
    """Median x (m) where the first falling liquid lands, predicted by rolling the model
    ``steps`` steps from ``state`` at time ``t`` under ``parts.poses_at`` (a :class:`CatchParts`
    or a catalogue setup: its script; no gradient; the catcher stays at ``x_catcher``); NaN
    when nothing falls within them or the source is empty."""
    parts = parts if isinstance(parts, CatchParts) else CatchParts.of(parts)
    if float(held(model, state, parts.src, parts.src_obj)[0].mean()) < FALLING_MIN:
        return float("nan")
    s = state
    with torch.no_grad():
        for j in range(steps):
            poses = torch.as_tensor(np.array(parts.poses_at(t + (j + 1) * model.dt), float))
            poses[parts.dst, 0] = x_catcher
            s = step(model, s, poses.to(s.x))
            if (j + 1) % 4 == 0 or j + 1 == steps:
                land = CatchLoss(parts, model, s, x_catcher).landing(s)
                if land is not None:
                    return float(land[0].median())
    return float("nan")


class CatchMPC:
    """The catching MPC (module doc), one update at a time: :func:`run_catch`'s and a
    session's catch task's. Keeps the plan and the predicted first landing (``aim``, re-run
    every ``LOOKAHEAD_EVERY`` model steps while nothing falls)."""

    def __init__(self, model, space: ControlSpace, *, horizon: int = 10, step_size: float = 0.1):
        self.mpc = MPC(model, space, None, horizon=horizon, step_size=step_size)
        self.aim, self.steps, self.updates = float("nan"), 0, 0

    def loss(self, parts: CatchParts, state, t: float, x: float, elapsed: int = 1) -> CatchLoss:
        """The loss of the rollout from ``state`` at time ``t`` with the catcher at ``x``;
        ``elapsed``: model steps since the previous call (the aim is refreshed on schedule)."""
        prev = self.steps
        if self.updates:
            self.steps += int(elapsed)
        self.updates += 1
        loss = CatchLoss(parts, self.mpc.model, state, x)
        if loss.landing(state) is not None:
            self.aim = float("nan")                                   # the stream is here: aim at it
        elif self.updates == 1 or self.steps // LOOKAHEAD_EVERY > prev // LOOKAHEAD_EVERY:
            self.aim = first_landing(parts, self.mpc.model, state, t, x)
        loss.aim = self.aim if np.isfinite(self.aim) else None
        return loss

    def update(self, state, q: torch.Tensor, space: ControlSpace, loss: CatchLoss, elapsed: int = 1) -> torch.Tensor:
        """One gradient step on the plan; the control (m/s, (1,)) to run until the next update.
        ``elapsed`` > 1: the plan's first elapsed − 1 steps are past."""
        self.mpc.skip(elapsed)
        self.mpc.space, self.mpc.loss = space, loss
        return self.mpc.update(state, q)[0]

    def state_dict(self) -> dict:
        return {"aim": float(self.aim), "steps": int(self.steps), "updates": int(self.updates),
                "plan": self.mpc.plan.clone()}

    def load_state_dict(self, d: dict) -> None:
        self.aim, self.steps, self.updates = float(d["aim"]), int(d["steps"]), int(d["updates"])
        self.mpc.plan = d["plan"].clone()


@dataclass
class CatchRun:
    motion: int
    caught: float          # share of the liquid in the catcher at the end
    left_source: float     # share that left the source
    spilled: float         # neither in the source nor in the catcher
    xs: np.ndarray         # (steps,) catcher x after each step, m
    wall_s: float
    update_s: float        # s per control step: an MPC update or a policy evaluation, plus the model step
    states: list = dataclasses.field(default_factory=list)   # keep_states: the state before each step
    aims: np.ndarray = None   # keep_states: the predicted first landing before each step (NaN: none)


def run_catch(setup, model, state, *, horizon: int = 10, step_size: float = 0.1,
              seconds: float | None = None, progress: bool = False, policy=None,
              keep_states: bool = False) -> CatchRun:
    """Run the catching task over the scene's duration (or ``seconds``) from ``state``: by
    the MPC, or by ``policy`` (a :class:`liquidtwin.control.policy.CatchPolicy`, which sees
    only its image of the particles). ``keep_states``: return the state before every step
    (the demonstrations a policy is trained from)."""
    src, dst = setup.index("source"), setup.index("catcher")
    src_obj, dst_obj = setup.objects[src].model, setup.objects[dst].model
    n = int(state.x.shape[0])
    parts = CatchParts.of(setup)
    ctrl = CatchMPC(model, catch_space(setup, 0.0, horizon, model.dt), horizon=horizon, step_size=step_size)
    q = torch.tensor([float(setup.poses_at(0.0)[dst][0])], dtype=torch.float64)
    steps = int(round((seconds or setup.duration) / model.dt))
    xs, states, aims = [], [], []
    t0 = time.perf_counter()
    for i in tqdm(range(steps), desc=f"catch, motion {setup.notes.get('motion')}", unit="step",
                  disable=not progress, leave=False):
        t = i * model.dt
        space = catch_space(setup, t, horizon if policy is None else 1, model.dt)
        if policy is None or keep_states:
            loss = ctrl.loss(parts, state, t, float(q[0]))
        if keep_states:
            states.append(state)
            aims.append(ctrl.aim)
        if policy is not None:
            with torch.no_grad():
                u = policy.control(state.x, q, setup)
        else:
            u = ctrl.update(state, q, space, loss)
        q = space.positions(q, u[None], model.dt)[0]
        poses = space.base_poses[0].clone()                         # the scene at t + dt …
        poses[dst] = space.to_pose(q[None])[0]                      # … with the catcher where it went
        with torch.no_grad():
            state = step(model, state, poses.to(state.x))
        xs.append(float(q[0]))
    wall = time.perf_counter() - t0
    in_src = held(model, state, src, src_obj)[0]
    in_dst = held(model, state, dst, dst_obj)[0]
    return CatchRun(int(setup.notes.get("motion", -1)), float(in_dst.sum()) / n, 1.0 - float(in_src.sum()) / n,
                    float((~(in_src | in_dst)).sum()) / n, np.asarray(xs), wall, wall / max(steps, 1), states,
                    np.asarray(aims))
