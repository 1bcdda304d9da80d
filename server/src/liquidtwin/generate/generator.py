"""``liquidtwin generate``: a recording as a robot lab would capture it, with an effect hidden in it.

Pipeline: scene (seeded) → world (the truth's physics, with the effect) → fill and settle →
simulate → sensors: tracker poses (noisy, 60 Hz), thermal liquid masks (30 Hz, noisy, some
dropped, shifted in time or seen from a mis-calibrated camera when the effect says so),
optional RGB → MCAP (Foxglove schemas + the scene spec) and, beside it, the truth: what the
effect was, the world's parameters and the true particles (``REC.truth.json`` +
``REC.truth.npz``). Nothing in the MCAP names the effect or its value.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb
from tqdm.auto import tqdm

from ..camera import Camera
from ..recordings import CameraInfo, RecordingWriter
from ..scenes.motions import quat_axis_angle, quat_multiply
from ..sensors import MaskNoise, PoseNoise, RGBParams, corrupt_mask, dropped_frames, noisy_poses, synth_rgb
from . import catalog
from .effects import EFFECTS, Effect, sample_effect
from .observe import liquid_mask, object_labels, particle_radius
from .world import build_world, initial_state, model_iterations, simulate

#: Stamps start here (2026-01-01T00:00:00Z) so recordings look like real logs.
START_NS = 1_767_225_600_000_000_000
POSE_HZ = 60
CAMERA_HZ = 30
#: Truth file format version.
TRUTH_VERSION = 1
#: The generator's world: bumped whenever what it writes for a given case and seed changes
#: (physics, sensors, scenes), so cached benchmark recordings of an older world are redone
#: (``evaluate.benchmark.cached``). 2: stop 41, the world keeps the model's cohesion
#: (``reference_iterations``). Recordings without it are from before.
WORLD_VERSION = 2


@dataclass(frozen=True)
class Generated:
    """What :func:`generate` wrote and the headline facts (for the CLI's table)."""

    mcap: Path
    truth: Path
    particles: int
    steps: int
    masks: int
    dropped: int
    fill_ml: dict


def _stated_camera(camera: Camera, effects) -> Camera:
    """The calibration the recording states: the true one, or one that is off (camera_offset)."""
    effect = next((e for e in effects if e.name == "camera_offset"), None)
    if effect is None:
        return camera
    pose = camera.pose.detach().double().numpy()
    turn = quat_axis_angle(effect.extra["axis"], math.radians(effect.value))
    wrong = np.concatenate([pose[:3] + np.asarray(effect.extra["shift_m"]), quat_multiply(turn, pose[3:])])
    return camera.with_pose(torch.as_tensor(wrong, dtype=camera.pose.dtype))


def _camera_info(camera: Camera) -> CameraInfo:
    return CameraInfo(name=camera.name, width=camera.width, height=camera.height,
                      K=camera.K.detach().double().numpy(), D=camera.distortion.detach().double().numpy(),
                      pose=camera.pose.detach().double().numpy())


def scene_spec(setup, session_id: str = "generated") -> pb.SceneSpec:
    """The SceneSpec a recording states (stated fills, liquidtwin's own solver settings)."""
    spec = pb.SceneSpec(name=setup.name, motion=setup.motion, duration_s=setup.duration,
                        cameras=[c.name for c in setup.cameras])
    spec.header.session_id = session_id
    spec.simulation.h = setup.h
    spec.simulation.dt = setup.dt
    spec.simulation.iterations = model_iterations(setup)
    spec.simulation.spacing = 0.55 * setup.h
    for k, v in setup.motion_params.items():
        spec.motion_params[k] = float(v)
    p0 = setup.poses_at(0.0)
    for o, pose in zip(setup.objects, p0):
        item = spec.objects.add(name=o.name, model=o.model_name, container=o.container)
        item.initial_pose.extend(float(a) for a in pose)
        for k, v in o.params.items():
            item.params[k] = float(v)
    for name, ml in setup.fills:
        if ml > 0:                               # an empty container states no fill
            spec.fills.add(container=name, volume_ml=float(ml))
    return spec


def generate(scene: str, out: str | Path, *, effects=(), seed: int = 0, quick: bool = False, rgb: bool = False, noise: bool = True,
             progress: bool = False, choices: dict | None = None) -> Generated:
    """Write ``out`` (MCAP) and ``out`` with suffix ``.truth.json`` / ``.truth.npz``.

    Args:
      scene: a name from ``generate.catalog.SCENES``.
      effects: (name, value) pairs or (name, value, extra) triples, names from
        ``generate.effects.EFFECTS``; a None value is drawn from the effect's realistic range;
        ``extra`` fixes secondary parameters (e.g. ``{"leg": 0.0}``: the left pipe leg). The name ``"random"`` picks one effect or
        none (equal odds) from the seed — for blind tests.
      seed: randomises the scene, the world, the effect's extras and all sensor noise.
      quick: the short, small variant (tests). rgb: also write synthetic RGB frames.
      noise: pose/mask noise and dropped frames (off: perfect sensors, for golden files).
      choices: pour scenes only — fix ``source``, ``target`` or ``fraction`` instead of
        drawing them from the seed (``catalog.build_setup``).
    """
    out = Path(out)
    # Independent streams: the same seed gives the same scene, world jitter and sensor noise
    # whatever effects are hidden, so an effect is the only difference between two recordings.
    scene_rng, effect_rng, world_rng, rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4))
    setup = catalog.build_setup(scene, scene_rng, quick, **(choices or {}))
    effs = _resolve(effects, effect_rng)
    world = build_world(setup, effs, world_rng)
    state, reports = initial_state(world, setup, progress=progress)
    steps = int(math.ceil(setup.duration / setup.dt - 1e-9))
    x = simulate(world, setup, state, steps, progress=progress)
    n = x.shape[1]

    # Tracker poses at POSE_HZ.
    pose_every = max(1, round(1.0 / (POSE_HZ * setup.dt)))
    pose_steps = np.arange(0, steps + 1, pose_every)
    true_poses = np.stack([setup.poses_at(k * setup.dt) for k in pose_steps])
    written = noisy_poses(true_poses, rng, PoseNoise() if noise else PoseNoise.NONE)

    # Camera frames at CAMERA_HZ, every few pose samples; the image stamped t shows the world
    # at t − offset.
    offset = sum(e.value for e in effs if e.name == "time_offset")
    frame_of = {int(i): j for j, i in enumerate(range(0, len(pose_steps), max(1, round(POSE_HZ / CAMERA_HZ))))}
    frame_steps = pose_steps[list(frame_of)]
    keep = dropped_frames(len(frame_steps), rng) if noise else np.ones(len(frame_steps), bool)
    mask_noise = _mask_noise(rng) if noise else MaskNoise.NONE
    radius = particle_radius(world.model.spacing)
    meshes = [o.model.mesh if o.model is not None else None for o in setup.objects]
    # Occluders: the objects, not the table (the camera and the liquid are above it).
    solid = [k for k, o in enumerate(setup.objects) if o.name != catalog.TABLE]
    occluders = [world.model.objects[k] for k in solid]
    colors = rng.uniform(0.15, 0.9, (len(meshes), 3))
    look = RGBParams.sample(rng) if rgb else None      # one table, texture and lighting per recording

    spec = scene_spec(setup)
    truth_frames = []
    out.parent.mkdir(parents=True, exist_ok=True)
    bar = tqdm(total=len(frame_steps), desc="sensors", unit="frame", disable=not progress, leave=False)
    with RecordingWriter(out, spec) as rec:
        for cam in setup.cameras:
            rec.write_camera(cam.name, _camera_info(_stated_camera(cam, effs)), START_NS)
        t_pose = START_NS + np.round(pose_steps * setup.dt * 1e9).astype(np.int64)
        written_frames = 0
        for i, k in enumerate(pose_steps):
            rec.write_poses(int(t_pose[i]), setup.names, written[i])
            if i in frame_of:
                j = frame_of[i]
                bar.update()
                if not keep[j]:
                    continue
                t_world = k * setup.dt - offset
                kw = int(np.clip(round(t_world / setup.dt), 0, steps))
                poses_w = torch.as_tensor(setup.poses_at(kw * setup.dt))
                stamp = int(t_pose[i])
                for cam in setup.cameras:
                    mask, thick = liquid_mask(cam, torch.from_numpy(x[kw]), occluders, poses_w[solid], radius)
                    rec.write_mask(cam.name, stamp, corrupt_mask(mask, rng, mask_noise))
                    if rgb:
                        labels = object_labels(cam, meshes, poses_w.numpy())
                        image = synth_rgb(rng, liquid_thickness=thick, liquid_mask=mask, labels=labels,
                                          object_colors=colors, params=look)
                        rec.write_image(cam.name, stamp, image, format="jpeg")
                truth_frames.append((stamp, kw))
                written_frames += 1
    bar.close()

    truth_json = out.with_suffix(".truth.json")
    truth_npz = out.with_suffix(".truth.npz")
    np.savez_compressed(truth_npz, pose_stamps_ns=t_pose, particles=x[pose_steps].astype(np.float32),
                        true_poses=true_poses, frame_stamps_ns=np.array([f[0] for f in truth_frames], np.int64),
                        frame_world_step=np.array([f[1] for f in truth_frames], np.int64),
                        dt=np.float64(setup.dt))
    truth = {
        "version": TRUTH_VERSION, "world_version": WORLD_VERSION, "scene": scene, "seed": seed, "quick": quick, "choices": {k: v for k, v in (choices or {}).items() if v is not None}, "rgb": rgb, "noise": noise,
        "effect": effs[0].as_dict() if len(effs) == 1 else None,
        "effects": [e.as_dict() for e in effs],
        "world": {"params": world.params, "iterations": world.model.iterations, "h": setup.h, "dt": setup.dt,
                  "relaxation": world.model.relaxation, "reference_iterations": world.model.reference_iterations},
        "fill_ml": {"stated": world.stated_ml, "true": world.fill_ml,
                    "reports": {k: _plain(r) for k, r in reports.items()}},
        "cameras": {c.name: {"true_pose": c.pose.detach().double().tolist()} for c in setup.cameras},
        "mask_noise": _plain(mask_noise), "frames": {"written": written_frames, "total": len(frame_steps)},
        "setup": setup.notes, "particles_file": truth_npz.name,
    }
    truth_json.write_text(json.dumps(truth, indent=2, default=float) + "\n")
    return Generated(out, truth_json, n, steps, written_frames, len(frame_steps) - written_frames, world.fill_ml)


def _mask_noise(rng: np.random.Generator) -> MaskNoise:
    """One recording's mask quality. The liquid covers well under 1 % of a scene's pixels, so
    false liquid is a few specks per frame (≤ 3e-4 of dry pixels), not a haze."""
    return MaskNoise(miss=float(rng.uniform(0.0, 0.1)), false=float(rng.uniform(0.0, 3e-4)),
                     ragged_px=float(rng.uniform(0.0, 1.5)), blob_px=float(rng.uniform(2.0, 6.0)),
                     speck_share=float(rng.uniform(0.1, 0.5)))


def _resolve(effects, rng: np.random.Generator) -> list[Effect]:
    out = []
    for item in effects:
        name, value, extra = (tuple(item) + (None,))[:3]
        if name == "random":
            names = [None] + list(EFFECTS)
            name = names[int(rng.integers(len(names)))]
            if name is None:
                continue
            value = None
        if any(e.name == name for e in out):
            raise ValueError(f"effect {name!r} given twice")
        out.append(sample_effect(name, rng, value, extra))
    return out


def _plain(obj):
    if dataclasses.is_dataclass(obj):
        return {k: _plain(v) for k, v in dataclasses.asdict(obj).items()}
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (np.generic, np.ndarray)):
        return obj.tolist()
    return obj


def listing() -> list[str]:
    """One line per scene and per effect (``liquidtwin generate --list``)."""
    lines = [f"scene {name}" for name in catalog.SCENES]
    lines += [f"effect {e.name}" for e in EFFECTS.values()]
    return lines
