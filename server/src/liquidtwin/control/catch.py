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
left the source and are still above that height. While nothing falls (before the pour,
after it: less than ``FALLING_MIN`` of the liquid) the loss is the squared distance from
where the catcher is: it holds still.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import torch
from tqdm.auto import tqdm

from ..scenes import motions as mo
from ..scenes.liquid_level import held
from ..sim import step
from .mpc import MPC, ControlError, ControlSpace

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


def catch_space(setup, t: float, horizon: int, dt: float) -> ControlSpace:
    """ControlSpace of the catcher's x from time ``t``: the other objects at their scripted
    poses of each planned step ((horizon, M, 7) base poses)."""
    k = setup.index("catcher")
    base = torch.as_tensor(np.stack([setup.poses_at(t + (i + 1) * dt) for i in range(horizon)]), dtype=torch.float64)
    rest = base[0, k].clone()
    x0 = float(setup.objects[k].motion(0.0)[0])

    def to_pose(q):
        pose = rest.to(q.dtype).expand(q.shape[0], 7).clone()
        return torch.cat([q[:, :1], pose[:, 1:]], dim=1)

    return ControlSpace(base, k, to_pose, torch.tensor([x0 - RANGE], dtype=torch.float64),
                        torch.tensor([x0 + RANGE], dtype=torch.float64), torch.tensor([MAX_SPEED], dtype=torch.float64))


@dataclass
class CatchRun:
    motion: int
    caught: float          # share of the liquid in the catcher at the end
    left_source: float     # share that left the source
    spilled: float         # neither in the source nor in the catcher
    xs: np.ndarray         # (steps,) catcher x, m
    wall_s: float
    update_s: float


def run_catch(setup, model, state, *, horizon: int = 10, step_size: float = 0.5,
              seconds: float | None = None, progress: bool = False) -> CatchRun:
    """Run the catching MPC over the scene's duration (or ``seconds``) from ``state``."""
    src, dst = setup.index("source"), setup.index("catcher")
    src_obj, dst_obj = setup.objects[src].model, setup.objects[dst].model
    n = int(state.x.shape[0])
    away = {"ids": torch.zeros(0, dtype=torch.long)}
    hold = {"x": 0.0}

    def loss(s, k, q):
        x, v = s.by_id()
        x, v = x[away["ids"]], v[away["ids"]]
        above = x[:, 1] > rim_y
        if int(above.sum()) < FALLING_MIN * n:        # (next to) nothing falling: hold still
            return (q[0] - float(hold["x"])) ** 2
        x, v = x[above], v[above]
        # where each falling particle crosses the catcher's rim height (ballistic)
        t_hit = (v[:, 1] + torch.sqrt(v[:, 1] ** 2 + 2.0 * G * (x[:, 1] - rim_y))) / G
        land_x, land_z = x[:, 0] + v[:, 0] * t_hit, x[:, 2] + v[:, 2] * t_hit
        return torch.sqrt((land_x - q[0]) ** 2 + (land_z - rest_z) ** 2 + 1e-12).mean()

    rim_y = float(setup.poses_at(0.0)[dst][1]) + float(dst_obj.rim_height)
    rest_z = float(setup.poses_at(0.0)[dst][2])
    mpc = MPC(model, catch_space(setup, 0.0, horizon, model.dt), loss, horizon=horizon, step_size=step_size)
    q = torch.tensor([float(setup.poses_at(0.0)[dst][0])], dtype=torch.float64)
    steps = int(round((seconds or setup.duration) / model.dt))
    xs = []
    t0 = time.perf_counter()
    for i in tqdm(range(steps), desc=f"catch, motion {setup.notes.get('motion')}", unit="step",
                  disable=not progress, leave=False):
        t = i * model.dt
        away["ids"] = torch.as_tensor(np.flatnonzero(~held(model, state, src, src_obj)[0]))
        mpc.space = catch_space(setup, t, horizon, model.dt)
        hold["x"] = float(q[0])
        u, _ = mpc.update(state, q)
        q = mpc.space.positions(q, u[None], model.dt)[0]
        poses = mpc.space.base_poses[0].clone()                    # the scene at t + dt …
        poses[dst] = mpc.space.to_pose(q[None])[0]                  # … with the catcher where it went
        with torch.no_grad():
            state = step(model, state, poses.to(state.x))
        xs.append(float(q[0]))
    wall = time.perf_counter() - t0
    in_src = held(model, state, src, src_obj)[0]
    in_dst = held(model, state, dst, dst_obj)[0]
    return CatchRun(int(setup.notes.get("motion", -1)), float(in_dst.sum()) / n, 1.0 - float(in_src.sum()) / n,
                    float((~(in_src | in_dst)).sum()) / n, np.asarray(xs), wall, wall / max(steps, 1))
