"""Roll a (possibly extended) model through an episode and draw what its camera would see.

:class:`Simulator` builds the episode's scene once (objects, model, the stated fill settled),
then :meth:`Simulator.rollout` runs a model :class:`~.model.Extension` open loop through the
recorded object poses and keeps every step's particles, so observation candidates (time and
camera offsets) re-draw the same rollout instead of simulating again. Model masks are the
session's: each visible particle drawn as its projected sphere.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..camera import in_view, segment_blocked, sphere_coverage, sphere_radius_px
from ..generate.catalog import source_sites
from ..scenes.fill import fill_container
from ..scenes.spec import simulation_settings, solve_with
from ..session._build import SETTLE_S, build_scene
from ..session._cull import cull_fallen
from ..session.engine import MIN_RADIUS_PX, NEAR_M, OCCLUSION_MARGIN_PX
from ..sim import make_state, particle_radius, step
from .episode import Episode
from .model import Extension, apply_physics, camera_for


@dataclass(frozen=True, eq=False)
class Trajectory:
    """One rollout: ``x[k]`` (N_k, 3) float32 particles after step k (k = 0 is the fill, time
    k·dt), ``poses`` (S + 1, n, 7) the object poses used, ``ext`` the extension simulated.
    ``hidden``: what :meth:`Simulator.render` has learnt of which particles the occluders hide
    from a camera centre, {(centre, k): (N_k,) int8, −1 not yet marched, 0 seen, 1 hidden}."""

    x: list
    poses: np.ndarray
    dt: float
    ext: Extension
    hidden: dict = field(default_factory=dict, repr=False)

    def at(self, t: float) -> int:
        return int(np.clip(round(t / self.dt), 0, len(self.x) - 1))


#: Initial-velocity jitter of an ensemble's draws, m/s (the null realisations' ``NULL_JITTER``):
#: far below anything a camera sees, enough to send a pour into another of its flows.
DRAW_JITTER = 1e-3


class Simulator:
    """The episode's scene, built once; rollouts of any extension of its model.
    ``extra_iterations``: solver iterations added to the recording's stated count (the fill
    is settled with them too), with the stated count's cohesion (``FluidModel.reference_iterations``).
    ``jitter``: rollouts from the fill start with this initial-velocity jitter, m/s, the same
    draw every time (``Options.prediction_jitter``)."""

    #: Seed of the prediction jitter's one draw; draw k of an ensemble uses this + k.
    JITTER_SEED = 12345

    def __init__(self, ep: Episode, *, progress: bool = False, extra_iterations: int = 0, jitter: float = 0.0):
        self.ep = ep
        self.jitter = float(jitter)
        spec = ep.spec
        if extra_iterations:
            spec = pb.SessionSpec()
            spec.CopyFrom(ep.spec)
            solve_with(spec.scene, int(simulation_settings(ep.spec.scene)["iterations"]) + extra_iterations)
        self.scene = build_scene(spec, progress=progress)
        self.model = self.scene.model
        self.dt = float(self.model.dt)
        self.radius_m = particle_radius(float(self.model.spacing))
        self.steps = int(np.ceil(ep.duration_s / self.dt - 1e-9))
        self.step_poses = ep.poses_at(np.arange(self.steps + 1) * self.dt)
        names = list(self.scene.names)
        fills = {f.container: f for f in ep.spec.scene.fills}
        self.source = next(iter(fills))
        self.source_index = names.index(self.source)
        obj = self.scene.objects[self.source_index]
        stated = self.scene.fills[self.source].settled_ml
        try:
            self.sites = source_sites(self.source_index, obj, stated)
        except (AttributeError, ValueError):
            self.sites = None            # not a round container: no leak / blockage site
        self._fills: dict[float, tuple] = {1.0: self.scene.state.by_id()}

    def initial(self, scale: float) -> tuple[torch.Tensor, torch.Tensor]:
        """(x, v) of the fill with the source's stated volume × ``scale`` (cached), at most
        full to the rim: no container starts fuller than it can hold (a 90 % cup told +20 %
        starts full)."""
        key = round(float(scale), 4)
        if key not in self._fills:
            k = self.source_index
            rep = self.scene.fills[self.source]
            poses = torch.as_tensor(self.scene.initial_poses)
            obj = self.scene.objects[k]
            s, _ = fill_container(self.model, poses, k, obj,
                                  volume_ml=min(max(rep.asked_ml * key, 1e-3), obj.capacity_ml), settle_s=SETTLE_S)
            xs, vs = s.by_id()
            # other containers' fills are kept as they are
            x0, v0 = self._fills[1.0]
            others = [n for n in self.scene.fills if n != self.source]
            if others:
                m = sum(self.scene.fills[n].particles for n in others)
                xs, vs = torch.cat([xs, x0[-m:]]), torch.cat([vs, v0[-m:]])
            self._fills[key] = (xs.float(), vs.float())
        return self._fills[key]

    def max_fill_scale(self) -> float:
        """The largest fill scale that still changes the fill: the source full to its rim."""
        rep = self.scene.fills[self.source]
        return float(self.scene.objects[self.source_index].capacity_ml) / max(float(rep.asked_ml), 1e-9)

    def rollout(self, ext: Extension, *, steps: int | None = None, initial=None, poses=None) -> Trajectory:
        """Run ``ext``'s model open loop from its initial fill (or ``initial`` = (x, v)) through
        the recorded poses (or ``poses``: another (T, n, 7) series on the recording's pose
        sample times)."""
        model = apply_physics(ext, self.model, self.sites)
        if initial is None:
            x0, v0 = self.initial(ext.fill_scale)
            if ext.draw > 0:                # realisation k of the prediction (Extension.draw)
                g = torch.Generator().manual_seed(self.JITTER_SEED + ext.draw)
                v0 = v0 + DRAW_JITTER * torch.randn(v0.shape, generator=g, dtype=v0.dtype)
            elif self.jitter > 0:
                g = torch.Generator().manual_seed(self.JITTER_SEED)
                v0 = v0 + self.jitter * torch.randn(v0.shape, generator=g, dtype=v0.dtype)
        else:
            x0, v0 = initial
        step_poses = self.step_poses if poses is None else self.ep.poses_at(np.arange(self.steps + 1) * self.dt, poses)
        poses = torch.as_tensor(step_poses)
        state = make_state(x0, v0, poses=poses[0], dtype=torch.float32)
        n = self.steps if steps is None else min(steps, self.steps)
        xs = [state.by_id()[0].numpy().copy()]
        with torch.no_grad():
            for k in range(n):
                state = step(model, state, poses[k + 1].to(torch.float32))
                state, _ = cull_fallen(state, model.objects)
                xs.append(state.x.numpy().copy())
        return Trajectory(xs, step_poses[: n + 1], self.dt, ext)

    def render(self, traj: Trajectory, frames=None, *, ext: Extension | None = None) -> np.ndarray:
        """(F, H, W) bool model masks at the episode's mask ``frames`` (indices, default all),
        with the observation part (time / camera offset) of ``ext`` (default: the rollout's).

        Each particle is drawn when the camera sees it (``camera.visible``'s rule). Whether an
        occluder hides it depends only on the step and the camera's centre, which neither a
        time offset nor a camera rotation moves, so the march is kept in ``traj.hidden`` and
        the observation candidates' re-draws of one rollout march each particle once."""
        ext = traj.ext if ext is None else ext
        cam = camera_for(ext, self.ep.camera)
        frames = range(len(self.ep.frame_t)) if frames is None else frames
        occ = list(self.scene.occluders)
        grids = [self.model.objects[k] for k in occ]
        out = np.zeros((len(frames), cam.height, cam.width), bool)
        with torch.no_grad():
            for i, j in enumerate(frames):
                k = traj.at(float(self.ep.frame_t[j]) - ext.time_offset_s)
                x = torch.from_numpy(traj.x[k])
                if x.shape[0] == 0:
                    continue
                seen = self._seen(traj, k, cam, x, grids, occ)
                uv, depth = cam.project(x)
                r = sphere_radius_px(cam.fx, depth, self.radius_m, min_px=MIN_RADIUS_PX)
                out[i] = (sphere_coverage(uv, r, seen, cam.height, cam.width) > 0).cpu().numpy()
        return out

    def _seen(self, traj: Trajectory, k: int, cam, x: torch.Tensor, grids: list, occ: list) -> torch.Tensor:
        """(N,) bool: step k's particles ``x`` that ``cam`` sees (as ``camera.visible`` with the
        session's margin and near plane), marching only those not marched before from this
        camera centre (``Trajectory.hidden``)."""
        seen = in_view(cam, x, OCCLUSION_MARGIN_PX, NEAR_M)
        if not grids or not bool(seen.any()):
            return seen
        centre = cam.position.detach().to(x.dtype)
        key = (tuple(centre.tolist()), k)
        state = traj.hidden.get(key)
        if state is None:
            state = traj.hidden[key] = torch.full((x.shape[0],), -1, dtype=torch.int8)
        todo = torch.nonzero(seen & (state < 0)).squeeze(1)
        if todo.numel():
            poses = torch.as_tensor(traj.poses[k], dtype=torch.float32)[occ]
            state[todo] = segment_blocked(x[todo], centre, grids, poses).to(torch.int8)
        return seen & (state == 0)
