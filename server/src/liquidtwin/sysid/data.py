"""Ground-truth sequences for system identification (thesis §8.3.1).

A :class:`Sequence` is what parameter estimation fits: a scene (rebuilt deterministically
from its catalogue name, seed and ``quick`` flag), the objects' poses at every simulation
step, and the true particles (positions and velocities, by particle id) at every step. The
thesis generated its 9 ladle sequences in FleX; liquidtwin generates them with its own
SPNets model and known parameters (:func:`simulate_sequence`), so the fit has a truth to
reach. Sequences are saved as ``.npz`` (arrays + a JSON header; never pickle).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from ..camera import Camera
from ..generate.catalog import build_setup
from ..generate.world import model_for
from ..scenes.fill import fill_container
from ..sim import FluidModel, make_state, step

#: Version of the .npz sequence file.
FILE_VERSION = 1


class SequenceError(ValueError):
    """A sequence file or request that cannot be used (says why)."""


@dataclass(frozen=True, eq=False)
class Sequence:
    """True particles of one scene over time.

    Attributes:
      scene, seed, quick: the catalogue scene (``liquidtwin generate --list``) and its draw.
      model: the scene's FluidModel (objects, dt, h, solver settings; its ``params`` are the
        model defaults — a fit replaces the ones it estimates).
      poses: (T+1, M, 7) float32 object poses at step k (time k·dt).
      x, v: (T+1, N, 3) float32 particle positions, m, and velocities, m/s, by id.
      camera: the scene's camera (used by the projection loss).
      truth: {parameter: value} the sequence was simulated with ({} when unknown).
    """

    scene: str
    seed: int
    quick: bool
    model: FluidModel
    poses: torch.Tensor
    x: torch.Tensor
    v: torch.Tensor
    camera: Camera
    truth: dict = field(default_factory=dict)

    @property
    def steps(self) -> int:
        return int(self.x.shape[0]) - 1

    @property
    def particles(self) -> int:
        return int(self.x.shape[1])


def scene_model(scene: str, seed: int, quick: bool):
    """(setup, FluidModel with the model's solver settings) of a catalogue scene."""
    try:
        setup = build_setup(scene, np.random.default_rng(seed), quick=quick)
    except ValueError as exc:
        raise SequenceError(str(exc)) from None
    model = model_for(setup)
    return setup, model


def simulate_sequence(scene: str = "ladle", truth: dict | None = None, *, seed: int = 0, quick: bool = True,
                      steps: int | None = None, progress: bool = False) -> Sequence:
    """Fill the scene's containers, then simulate its motion with fluid parameters ``truth``
    (e.g. ``{"lambda_c": 0.1, "lambda_v": 60}``; missing ones keep the defaults).

    ``steps``: how many steps (default: the whole motion). The fill settles with the true
    parameters, so every sequence starts from liquid at rest."""
    truth = dict(truth or {})
    setup, model = scene_model(scene, seed, quick)
    try:
        true_model = model.with_params(**truth)
    except (TypeError, ValueError) as exc:
        raise SequenceError(f"bad true parameters {truth}: {exc}") from None
    steps = int(round(setup.duration / setup.dt)) if steps is None else int(steps)
    if steps < 3:
        raise SequenceError(f"a sequence needs at least 3 steps, got {steps}")
    poses = torch.as_tensor(np.stack([setup.poses_at(k * setup.dt) for k in range(steps + 1)]), dtype=torch.float32)
    state = None
    for name, ml in setup.fills:
        k = setup.index(name)
        s, _ = fill_container(true_model, poses[0].double(), k, setup.objects[k].model, volume_ml=ml,
                              settle_s=0.5 if quick else 1.0)
        if state is not None:
            (xa, va), (xb, vb) = state.by_id(), s.by_id()
            s = make_state(torch.cat([xa, xb]), torch.cat([va, vb]), poses=poses[0])
        state = s
    xs = torch.empty((steps + 1,) + tuple(state.x.shape))
    vs = torch.empty_like(xs)
    xs[0], vs[0] = state.by_id()
    with torch.no_grad():
        for k in tqdm(range(steps), desc=f"truth {scene}", unit="step", disable=not progress, leave=False):
            state = step(true_model, state, poses[k + 1])
            xs[k + 1], vs[k + 1] = state.by_id()
    return Sequence(scene, seed, quick, model, poses, xs, vs, setup.cameras[0], truth)


def save_sequence(seq: Sequence, path) -> Path:
    """Write ``seq`` as a compressed .npz (arrays + a JSON header string)."""
    path = Path(path)
    header = json.dumps({"version": FILE_VERSION, "scene": seq.scene, "seed": seq.seed, "quick": seq.quick,
                         "truth": seq.truth})
    np.savez_compressed(path, header=np.array(header), poses=seq.poses.numpy(), x=seq.x.numpy(), v=seq.v.numpy())
    return path


def load_sequence(path) -> Sequence:
    """Read a sequence written by :func:`save_sequence`; SequenceError saying what is wrong
    (missing file, not a sequence, other version, arrays that disagree with the scene)."""
    path = Path(path)
    if not path.is_file():
        raise SequenceError(f"sequence file {str(path)!r} does not exist")
    try:
        with np.load(path, allow_pickle=False) as z:
            header = json.loads(str(z["header"]))
            poses, x, v = (torch.as_tensor(z[k], dtype=torch.float32) for k in ("poses", "x", "v"))
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as exc:
        raise SequenceError(f"{path}: not a liquidtwin sequence file ({exc})") from None
    if header.get("version") != FILE_VERSION:
        raise SequenceError(f"{path}: sequence file version {header.get('version')!r}, expected {FILE_VERSION}")
    if x.ndim != 3 or x.shape != v.shape or x.shape[-1] != 3 or poses.shape[0] != x.shape[0]:
        raise SequenceError(f"{path}: arrays disagree: x {tuple(x.shape)}, v {tuple(v.shape)}, "
                            f"poses {tuple(poses.shape)}")
    if not (torch.isfinite(x).all() and torch.isfinite(v).all() and torch.isfinite(poses).all()):
        raise SequenceError(f"{path}: the sequence holds NaN or infinite values")
    setup, model = scene_model(header["scene"], int(header["seed"]), bool(header["quick"]))
    if poses.shape[1:] != (len(setup.objects), 7):
        raise SequenceError(f"{path}: poses {tuple(poses.shape)} do not fit scene {header['scene']!r} "
                            f"({len(setup.objects)} objects)")
    return Sequence(header["scene"], int(header["seed"]), bool(header["quick"]), model, poses, x, v,
                    setup.cameras[0], dict(header.get("truth", {})))
