"""SessionEngine: one session's simulation, tracker and controller, without any networking.

The service owns one engine per session and calls it from one worker thread: ``advance`` on
every frame (object poses at a frame time), ``correct`` when the frame has a liquid mask,
then reads ``positions``/``speeds``/``volumes``/``control``. Everything runs under
``torch.no_grad()`` on the fast no-gradient paths of the simulator. ``state_dict`` holds all
that changes, so an engine built from the same spec and loaded with it continues bit for
bit (docs/service.md, "Nothing lost").
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from dataclasses import dataclass

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..camera import sphere_coverage, sphere_radius_px, visible
from ..recordings._interp import interpolate_poses
from ..scenes.liquid_level import fall_height, held, impact_iterations
from ..sim import FluidState, collide_move, particle_radius, step
from ..tracking import MapFilter, Observation, OpenLoop, WarpField
from ._build import build_scene
from ._checkpoint import engine_state, load_engine_state
from ._cull import cull_fallen
from ._extension import MAX_TIME_OFFSET_S, History, Prepared, prepare
from ._volumes import CavityVoxels, MaskVolumes, held_count_fast
from ._cameras import Cameras, check_pose
from ._pose_filter import PoseFilter, PoseFilterSettings
from ._task import create_task
from .errors import BAD_REQUEST, INFEASIBLE, UNKNOWN_NAME, EngineError
from .overlay import make_overlay

#: Nearest depth drawn, m, and the smallest model-mask disc, px. SPEC §2 draws 5 px discs:
#: the thesis's particles at its 640x512 camera. Here each particle is drawn as its own
#: sphere (radius from the rest volume, ``sim.particle_radius``) projected at its depth, so the
#: model mask means the same at any resolution and distance: with 5 px discs the *true*
#: particles score IOU 0.66 against their own full-size generated masks (0.35 at 320x240),
#: with projected spheres 0.87 (0.67) — bench/mask_ceiling.py (pour_hold, cup, 60 %, seed 5).
NEAR_M = 0.02
MIN_RADIUS_PX = 1.0
#: Occlusion margin, px: rays are tested from this far around a particle's centre.
OCCLUSION_MARGIN_PX = 5.0
STATE_VERSION = 1


@dataclass
class FrameResult:
    """steps: simulation steps taken; step_ms: their wall time; sim_lag_s: how far the sim
    clock jumped because of ``max_steps`` (0 normally); sim_time_s: session time after it, s."""

    steps: int
    step_ms: float
    sim_lag_s: float
    sim_time_s: float


@dataclass
class CorrectionResult:
    """iou: model vs observed mask before the correction; correction_ms: wall time of the whole
    call; overlay: (H, W, 3) uint8 RGB, Fig. 8.10 colours, before the correction (what the
    camera saw vs what the model predicted); pixel totals (overlap counted in both)."""

    iou: float
    correction_ms: float
    overlay: np.ndarray
    observed_px: int
    model_px: int
    overlap_px: int


def held_count(model, state, index: int, obj) -> int:
    """Particles container ``index`` holds (:func:`liquidtwin.scenes.liquid_level.held`),
    exact (one ray per particle); sessions use the voxelised :class:`CavityVoxels`."""
    return int(held(model, state, index, obj)[0].sum())


def _tracker(spec: pb.SessionSpec):
    mode = spec.tracking
    gain = float(spec.correction_gain)
    if not (math.isfinite(gain) and gain >= 0):
        raise EngineError(BAD_REQUEST, f"correction_gain must be >= 0 (0 = default), got {gain}")
    if mode == pb.OPEN_LOOP:
        return OpenLoop()
    if mode in (pb.TRACKING_MODE_UNSPECIFIED, pb.WARP_FIELD):
        return WarpField(gain) if gain > 0 else WarpField()
    if mode == pb.MAP_FILTER:
        return MapFilter()
    if mode == pb.SPNETS_PERCEPTION:
        from ..tracking import PerceptionWeightsError, SPNetsPerception
        try:
            return SPNetsPerception()
        except PerceptionWeightsError as e:
            raise EngineError(INFEASIBLE, f"tracking mode SPNETS_PERCEPTION: {e}") from e
    raise EngineError(BAD_REQUEST, f"unknown tracking mode {mode}")


class SessionEngine:
    """A session's liquid twin. Build with :meth:`create`; see the module doc."""

    @classmethod
    def create(cls, spec: pb.SessionSpec, *, device: str = "cpu", progress: bool = False,
               base_dir: str = ".") -> "SessionEngine":
        """Build objects, model and settled fill of ``spec.scene``, cameras from ``spec.cameras``
        and the tracker of ``spec.tracking``. ``device``: "cpu" (default: then ``spec.device``
        decides) or "cuda[:N]". Raises EngineError (BAD_REQUEST, UNKNOWN_NAME,
        INFEASIBLE: e.g. a tracking mode not implemented, no CUDA, more liquid than fits)."""
        device = device if device and device != "cpu" else (spec.device or "cpu")
        if not (device == "cpu" or device.startswith("cuda")):
            raise EngineError(BAD_REQUEST, f"device must be 'cpu' or 'cuda[:N]', got {device!r}")
        if device.startswith("cuda") and not torch.cuda.is_available():
            raise EngineError(INFEASIBLE, f"device {device!r} asked for, but this server has no CUDA device")
        tracker = _tracker(spec)
        PoseFilterSettings.from_spec(spec.pose_filter)          # refuse bad numbers before the slow build
        cameras = Cameras(spec)
        scene = build_scene(spec, device=device, progress=progress, base_dir=base_dir)
        return cls(spec, scene, cameras, tracker, device)

    def __init__(self, spec, scene, cameras, tracker, device):
        self.spec, self.device, self._scene = spec, device, scene
        self._cameras, self._tracker = cameras, tracker
        self.object_names = scene.names
        self.container_names = scene.containers
        self.dt = float(scene.model.dt)
        self._radius_m = particle_radius(float(scene.model.spacing))
        filtering = PoseFilterSettings.from_spec(spec.pose_filter)
        self._pose_filter = None if filtering is None else PoseFilter(filtering, len(scene.names))
        from ..discrepancy.model import Extension          # discrepancy builds on this package
        self._history = History()
        self._use(Prepared(Extension(), scene.model, scene.state, scene.ml_per_particle))
        self._capacity = {n: scene.objects[scene.names.index(n)].capacity_ml for n in scene.containers}
        self._voxels = {n: CavityVoxels(scene.objects[scene.names.index(n)]) for n in scene.containers}
        # Model-based volumes from the masks alone (SPEC §5): filters per container, in the checkpoint.
        self._mask_vol = MaskVolumes(scene.names, scene.objects, scene.containers, scene.occluders,
                                     scene.ml_per_particle * int(scene.state.x.shape[0]),
                                     float(scene.model.spacing),
                                     {f.container: float(f.volume_ml) for f in spec.scene.fills})
        self._reset_state()

    def _use(self, prep: Prepared) -> None:
        """Run ``prep``'s model (plus any term the tracker runs inside the solver) from now on."""
        self._ext, self._model, self._initial = prep.ext, prep.model, prep.initial
        self._ml_per_particle = prep.ml_per_particle
        extra = tuple(self._tracker.terms())
        self._step_model = dataclasses.replace(prep.model, terms=prep.model.terms + extra) if extra else prep.model
        self._history.span_s = min(max(prep.ext.time_offset_s, 0.0), MAX_TIME_OFFSET_S)
        self._history.clear()
        self._volumes = None

    def _reset_state(self) -> None:
        self._state = self._initial
        self._history.clear()
        self._history.push(0.0, self._initial)
        self._sim_t = 0.0
        self._frame_t: float | None = None
        self._frame_poses = self._scene.initial_poses.copy()
        self._frames = 0
        self._volumes: tuple | None = None
        self._mask_vol.reset()
        if self._pose_filter is not None:
            self._pose_filter.reset()
        self._task = None                      # PourTask, CatchTask or SendTask

    # ------------------------------------------------------------------ properties
    @property
    def camera_names(self) -> set:
        return set(self._cameras.known)

    @property
    def n_particles(self) -> int:
        return int(self._state.x.shape[0])

    @property
    def lost_particles(self) -> int:
        """Particles removed because they fell below every object (see ``_cull``)."""
        return int(self._initial.x.shape[0] - self._state.x.shape[0])

    @property
    def extension(self):
        """The loaded :class:`~liquidtwin.discrepancy.Extension` (name ``"none"``: the spec's model)."""
        return self._ext

    def prepare_extension(self, ext, *, initial: tuple | None = None) -> Prepared:
        """Check ``ext`` against this scene and build its model and initial fill without changing
        the session (slow for ``fill_error``: the source is refilled and settled). EngineError
        (BAD_REQUEST: missing/unknown/out-of-range parameter, no leak site; INFEASIBLE: the
        refill does not fit). ``initial``: a checkpoint's (x, v) fill instead of refilling."""
        return prepare(ext, self._scene, self.spec, self.device, initial)

    def load_extension(self, ext) -> None:
        """Run model extension ``ext`` (a :class:`~liquidtwin.discrepancy.Extension` or what
        :meth:`prepare_extension` made) from the next step on: its physics in every step, its
        camera rotation (``camera_offset``) in every comparison with a mask, its time offset
        (``time_offset``: a mask stamped t is compared with the particles of the step nearest
        t − s, at most ``MAX_TIME_OFFSET_S`` back; the tracker's correction moves the current
        particles with the same ids; s < 0 — a mask of the future — is compared with now), and
        its initial fill (``fill_error``): a reset starts from it, and so does the current
        episode when it has had no frame yet. ``reset`` keeps the extension; ``Extension()``
        (name "none") goes back to the spec's model."""
        prep = ext if isinstance(ext, Prepared) else self.prepare_extension(ext)
        self._use(prep)
        if self._frames == 0:
            self._state = self._initial
        self._history.push(self._sim_t, self._state)

    @property
    def sim_time_s(self) -> float:
        return self._sim_t

    def set_camera(self, name: str, *, K=None, D=None, width=None, height=None, pose=None) -> None:
        """Intrinsics K (3, 3), D (5,) plumb bob, size px, and/or pose (7,) camera → world
        (OpenCV frame); a camera is usable once it has both."""
        self._cameras.set(name, K=K, D=D, width=width, height=height, pose=pose)

    def camera_calibrations(self) -> dict:
        """name → (K (3, 3), D (5,), width, height, pose (7,)) of every usable camera."""
        out = {}
        for name, e in self._cameras.known.items():
            if {"K", "width", "height", "pose"} <= e.keys():
                out[name] = (np.asarray(e["K"], float).reshape(3, 3), np.asarray(e.get("D", np.zeros(5)), float),
                             int(e["width"]), int(e["height"]), np.asarray(e["pose"], float))
        return out

    def camera_size(self, name: str) -> tuple[int, int] | None:
        """(height, width) px of camera ``name`` if known."""
        return self._cameras.size(name)

    # ------------------------------------------------------------------ frames
    def advance(self, t_s: float, poses: dict, *, max_steps: int = 8) -> FrameResult:
        """Step from the previous frame's time to ``t_s`` (session s, first frame 0) with the
        named objects' (7,) poses interpolated (lerp/slerp) from the previous frame's; others
        keep theirs. Keeps the sub-step remainder; beyond ``max_steps`` the clock jumps."""
        t_s = float(t_s)
        if not math.isfinite(t_s) or t_s < 0:
            raise EngineError(BAD_REQUEST, f"frame time must be a finite number of s >= 0, got {t_s}")
        if self._frame_t is not None and t_s < self._frame_t:
            raise EngineError(BAD_REQUEST, f"frame time {t_s:.6f} s is before the previous frame's {self._frame_t:.6f} s")
        if isinstance(max_steps, bool) or int(max_steps) != max_steps or max_steps < 0:
            raise EngineError(BAD_REQUEST, f"max_steps must be a whole number >= 0, got {max_steps!r}")
        new = self._frame_poses.copy()
        measured = {}
        for name, p in poses.items():
            if name not in self.object_names:
                raise EngineError(UNKNOWN_NAME, f"no object {name!r} in the scene ({', '.join(self.object_names)})")
            measured[self.object_names.index(name)] = check_pose(p, f"object {name!r}")
        for j, p in measured.items():            # all checked: a bad frame changes nothing
            new[j] = p if self._pose_filter is None else self._pose_filter.update(t_s, j, p)
        t_prev = t_s if self._frame_t is None else self._frame_t
        n = max(0, int(math.floor((t_s - self._sim_t) / self.dt + 1e-6)))
        steps = min(n, int(max_steps))
        taus = self._sim_t + np.arange(1, steps + 1) * (n * self.dt / max(steps, 1)) - t_prev
        span = t_s - t_prev
        start = time.perf_counter()
        state = self._state
        if steps:
            ns = np.round(np.clip(taus / span if span > 0 else np.ones(steps), 0, 1) * 1e9).astype(np.int64)
            path = np.stack([interpolate_poses(np.array([0, 10**9]), np.stack([self._frame_poses[j], new[j]]), ns)
                             for j in range(len(new))], 1)          # (steps, M, 7)
            path = torch.as_tensor(path, device=state.x.device)
            with torch.no_grad():
                for k in range(steps):
                    state = step(self._step_model, state, path[k])
                    self._history.push(self._sim_t + (k + 1) * n * self.dt / steps, state)
                state, _ = cull_fallen(state, self._model.objects)
        ms = 1e3 * (time.perf_counter() - start)
        self._state = state
        self._sim_t += n * self.dt
        self._frame_t, self._frame_poses = t_s, new
        self._frames += 1
        self._volumes = None
        return FrameResult(steps, ms, (n - steps) * self.dt, self._sim_t)

    def correct(self, camera: str, mask: np.ndarray) -> CorrectionResult:
        """Compare the model with an observed liquid ``mask`` (H, W) bool of ``camera`` and apply
        the session's tracker (OPEN_LOOP only measures). IOU and overlay are from before. A
        loaded extension's camera rotation and time offset apply (:meth:`load_extension`)."""
        from ..discrepancy.model import camera_for
        start = time.perf_counter()
        cam = camera_for(self._ext, self._cameras.camera(camera))
        mask = np.asarray(mask)
        if mask.shape != (cam.height, cam.width):
            raise EngineError(BAD_REQUEST, f"mask of camera {camera!r} is {mask.shape}, its calibration says "
                                           f"{(cam.height, cam.width)} (H, W)")
        mask = mask if mask.dtype == bool else mask != 0
        s, model = self._compared(), self._model
        occ = list(self._scene.occluders)
        with torch.no_grad():
            poses = s.poses
            seen = visible(cam, s.x, [model.objects[k] for k in occ], poses[occ], margin_px=OCCLUSION_MARGIN_PX, near=NEAR_M)
            uv, depth = cam.project(s.x)
            r_px = sphere_radius_px(cam.fx, depth, self._radius_m, min_px=MIN_RADIUS_PX)
            cov = sphere_coverage(uv, r_px, seen, cam.height, cam.width)
            ov = make_overlay(mask, (cov > 0).cpu().numpy())
            if not isinstance(self._tracker, OpenLoop):
                obs_mask = torch.as_tensor(mask, device=s.x.device)
                cov = cov.to(s.x.device)
                typical = float(r_px[seen].median()) if bool(seen.any()) else MIN_RADIUS_PX
                obs = Observation(cam, obs_mask, s.x, s.v, uv, depth, seen, cov, typical, model, poses)
                corr = self._tracker.correct(obs)
                if corr is not None:
                    self._apply(corr, seen, s)
        self._mask_vol.update(self._frames, cam, mask, self._frame_poses)
        return CorrectionResult(ov.iou, 1e3 * (time.perf_counter() - start), ov.image, ov.observed_px,
                                ov.model_px, ov.overlap_px)

    def _compared(self) -> FluidState:
        """The state a mask of the latest frame is compared with: now, or with a time offset s > 0
        the kept step nearest the frame's time − s."""
        s = self._ext.time_offset_s
        past = self._history.at(self._frame_t - s) if s > 0 and self._frame_t is not None else None
        return self._state if past is None else past

    def _apply(self, corr, seen: torch.Tensor, src: FluidState) -> None:
        """Move the current particles by ``corr`` computed on ``src``'s ``seen`` particles (the
        current state, or a past one: then matched by particle id; culled ones are skipped)."""
        s = self._state
        idx = seen.nonzero().squeeze(1)
        dx, dv = corr.dx[idx].to(s.x), None if corr.dv is None else corr.dv[idx].to(s.v)
        if src is not s:
            where = torch.full((int(self._initial.x.shape[0]),), -1, dtype=torch.long, device=s.x.device)
            where[s.ids] = torch.arange(s.ids.numel(), device=s.x.device)
            at = where[src.ids[idx]]
            keep = at >= 0
            idx, dx = at[keep], dx[keep]
            dv = None if dv is None else dv[keep]
        x, v = s.x.clone(), s.v.clone()
        x[idx] = collide_move(self._model, s.x[idx], dx, s.poses, s.poses)
        if dv is not None:
            v[idx] = v[idx] + dv
        self._state = FluidState(x, v, s.ids, s.poses, s.t)
        self._volumes = None

    # ------------------------------------------------------------------ outputs
    def positions(self) -> np.ndarray:
        """(N, 3) float32 particle positions, m, world, ordered by particle id."""
        return self._state.by_id()[0].detach().cpu().numpy().astype(np.float32)

    def speeds(self) -> np.ndarray:
        """(N,) float32 particle speeds, m/s, ordered by particle id."""
        return self._state.by_id()[1].detach().norm(dim=1).cpu().numpy().astype(np.float32)

    def volumes(self) -> dict:
        """{container: ml}: particles the container holds × the fills' settled ml per particle
        (of the loaded extension's fill, see :meth:`load_extension`)."""
        if self._volumes is None or self._volumes[0] != self._frames:
            out = {}
            for name in self.container_names:
                k = self.object_names.index(name)
                out[name] = held_count_fast(self._scene.model, self._state, k, self._scene.objects[k],
                                            self._voxels[name]) * self._ml_per_particle
            self._volumes = (self._frames, out)
        return dict(self._volumes[1])

    def mask_volumes(self) -> dict:
        """{container: ml or None}: the model-based estimate from the liquid masks alone (SPEC §5,
        :class:`~liquidtwin.session._volumes.MaskVolumes`), the median of its volume filter; None
        until a mask has shown the container's interior."""
        return self._mask_vol.volumes()

    def meshes(self) -> dict:
        """{name: ((V, 3) float32 vertices m object frame, (F, 3) uint32 faces, is_container)}."""
        return {n: (np.asarray(o.mesh.vertices, np.float32), np.asarray(o.mesh.faces, np.uint32),
                    n in self.container_names) for n, o in zip(self.object_names, self._scene.objects)}

    # ------------------------------------------------------------------ task
    def set_task(self, task: pb.Task) -> None:
        """Set (or, with an empty task, cancel) the task: pour, catch_stream or send; EngineError
        if impossible. ``task.controller``: for a pour "pid" (default; the tracked target volume)
        or "mpc" (gradients through the session's model from the tracked particles, one update
        per frame); catch and send run "mpc" only."""
        if task.WhichOneof("kind") is None:
            self._task = None
            return
        copy = pb.Task()
        copy.CopyFrom(task)
        self._task = create_task(copy, self)
        self._warn_unsolved_impacts()

    def _warn_unsolved_impacts(self) -> None:
        """RuntimeWarning when the session's model solves fewer iterations than liquid falling
        between its containers needs (``scenes.liquid_level.impact_iterations``): a control task scored
        on where liquid lands then loses some of it to the solver's splash (the catching
        MPC lost 0-4.6 % a motion at 4 iterations, at most 1.5 % at 11, over three roundings:
        README, "Solver iterations and impacts")."""
        sc, model = self._scene, self._model
        containers = [sc.names.index(n) for n in sc.containers]
        need = impact_iterations(self._frame_poses, sc.objects, containers, model.dt, model.spacing)
        fall = fall_height(self._frame_poses, sc.objects, containers)
        speed = math.sqrt(2.0 * 9.81 * fall)
        if model.iterations < need:
            warnings.warn(f"liquid can fall {100 * fall:.0f} cm here and land at {speed:.1f} m/s; {model.iterations} "
                          f"solver iterations leave such impacts half solved and throw part of it back out; "
                          f"scene.simulation.iterations >= {need} (reference_iterations "
                          f"{model.reference_iterations or model.iterations}: the same liquid) solves them", RuntimeWarning, stacklevel=3)

    def control(self) -> pb.Control | None:
        """The controller's command after the latest frame; None without a task."""
        return None if self._task is None else self._task.control(self)

    # ------------------------------------------------------------------ lifecycle
    def reset(self) -> None:
        """Back to the settled initial fill at time 0; cameras kept, task cleared."""
        self._reset_state()
        self._tracker.load_state_dict({})

    def state_dict(self) -> dict:
        """Everything that changes (tensors, numbers, strings): torch.load(weights_only=True)."""
        out = engine_state(self)
        out["mask_volumes"] = self._mask_vol.state_dict()
        return out

    def load_state_dict(self, state: dict) -> None:
        """Continue from :meth:`state_dict` of an engine created from the same spec."""
        load_engine_state(self, state)
        self._mask_vol.load_state_dict(state.get("mask_volumes", {}))
