"""A robot's world for closed-loop runs: the generator's true physics (``world.py``: jittered
fluid parameters, more solver iterations, the hidden effect) stepped under the poses a
controller commands, and its sensors read frame by frame — noisy tracker poses and noisy
thermal liquid masks, as ``generate`` writes them to a recording. Where ``generate`` replays
a scripted motion, here the robot moves the objects (:meth:`RobotWorld.move`).

The truth (what each container really holds, the effect) is read from the world object by
whoever runs it (``examples/04_robot_world.py``), never sent to the server.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from ..control.tilt import tilt_from_upright
from ..scenes.liquid_level import held
from ..sensors import MaskNoise, PoseNoise, corrupt_mask, noisy_poses
from ..sim import step
from ..sim.sdf import interpolate_poses
from . import catalog
from .generator import _camera_info, _mask_noise, _resolve, _stated_camera, scene_spec
from .observe import liquid_mask, particle_radius
from .world import build_world, initial_state

#: Effects that change what the sensors report rather than the physics; a robot world runs
#: the physics live, so a time offset (masks of the past) is not modelled here.
UNSUPPORTED = ("time_offset",)


class RobotWorld:
    """The true world of one scene (see the module doc).

    Args:
      scene: a name from ``generate.catalog.SCENES``; seed: scene, world, effect and noise
        (the same seed → the same world as ``generate`` with that seed); quick: the small
        variant; effects: as :func:`liquidtwin.generate.generate`; noise: sensor noise on;
        choices: ``source`` / ``target`` / ``fraction`` of pour scenes.
    """

    def __init__(self, scene: str, *, seed: int = 0, quick: bool = True, effects=(), noise: bool = True,
                 choices: dict | None = None, progress: bool = False):
        scene_rng, effect_rng, world_rng, self._rng = (np.random.default_rng(s)
                                                       for s in np.random.SeedSequence(seed).spawn(4))
        self.setup = catalog.build_setup(scene, scene_rng, quick, **(choices or {}))
        self.effects = _resolve(effects, effect_rng)
        bad = [e.name for e in self.effects if e.name in UNSUPPORTED]
        if bad:
            raise ValueError(f"effect {bad[0]!r} is not modelled by the robot world (it runs the physics live)")
        self.world = build_world(self.setup, self.effects, world_rng)
        self.state, self.reports = initial_state(self.world, self.setup, progress=progress)
        self.poses = np.asarray(self.setup.poses_at(0.0), float)
        self.t = 0.0
        self.dt = float(self.setup.dt)
        self._mask_noise = _mask_noise(self._rng) if noise else MaskNoise.NONE
        # White tracker noise only: the drift of PoseNoise needs the whole sequence at once.
        self._pose_noise = dataclasses.replace(PoseNoise(), drift_m=0.0, drift_rad=0.0) if noise else PoseNoise.NONE
        self._solid = [k for k, o in enumerate(self.setup.objects) if o.name != catalog.TABLE]
        self._radius = particle_radius(self.world.model.spacing)
        self._ml = next(iter(self.reports.values())).particle_volume_ml if self.reports else 0.0

    def spec(self, session_id: str = "robot-world"):
        """The SceneSpec the robot states (stated fills, liquidtwin's solver settings)."""
        return scene_spec(self.setup, session_id)

    def cameras(self) -> dict:
        """{name: CameraInfo} as calibrated (off by the camera_offset effect, if hidden)."""
        return {c.name: _camera_info(_stated_camera(c, self.effects)) for c in self.setup.cameras}

    def move(self, poses: dict, seconds: float) -> int:
        """Step the world ``seconds`` (whole steps, at least one) while the named objects go
        from their poses now to ``poses`` ({name: (7,)}) linearly (nlerp); returns the steps."""
        target = self.poses.copy()
        for name, p in poses.items():
            p = np.asarray(p, float)
            if p.shape != (7,) or not np.isfinite(p).all():
                raise ValueError(f"pose of {name!r} must be 7 finite numbers, got {p}")
            target[self.setup.index(name)] = p
        n = max(1, int(round(seconds / self.dt)))
        p0, p1 = torch.as_tensor(self.poses), torch.as_tensor(target)
        with torch.no_grad():
            for k in range(n):
                poses = interpolate_poses(p0, p1, (k + 1) / n).to(self.state.x.dtype)
                self.state = step(self.world.model, self.state, poses)
        self.poses, self.t = target, self.t + n * self.dt
        return n

    @property
    def pose_noise(self):
        """The object tracker's noise (:class:`~liquidtwin.sensors.PoseNoise`): what its data sheet
        would state, e.g. for a session's pose filter."""
        return self._pose_noise

    def sense(self) -> tuple[dict, dict]:
        """What the sensors report now: ({object: (7,) tracked pose}, {camera: (H, W) bool mask})."""
        reported = noisy_poses(self.poses[None], self._rng, self._pose_noise)[0]
        poses = {name: reported[k] for k, name in enumerate(self.setup.names)}
        pw = torch.as_tensor(self.poses)
        occluders = [self.world.model.objects[k] for k in self._solid]
        masks = {}
        for cam in self.setup.cameras:
            mask, _ = liquid_mask(cam, self.state.x, occluders, pw[self._solid], self._radius)
            masks[cam.name] = corrupt_mask(mask, self._rng, self._mask_noise)
        return poses, masks

    def held_ml(self) -> dict:
        """{container: ml it truly holds now} (the settled fill's ml per particle)."""
        out = {}
        for k, o in enumerate(self.setup.objects):
            if o.container and o.model is not None:
                out[o.name] = float(held(self.world.model, self.state, k, o.model)[0].sum()) * self._ml
        return out

    def tilt(self, name: str) -> float:
        """Angle (rad) between object ``name``'s +y and the world's +y, now."""
        return tilt_from_upright(self.poses[self.setup.index(name)])
