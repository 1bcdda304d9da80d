"""The generator's "world": the true physics behind a recording.

The world runs the same SPNets step as liquidtwin, but with its own settings — more solver
iterations and fluid parameters jittered away from liquidtwin's defaults (a real liquid never
matches the model's defaults) — plus the hidden effect, applied as a term, a geometry edit or
a changed initial fill. Observation effects (time and camera offsets) are applied later, by
the generator, to what the sensors report.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from tqdm.auto import tqdm

from ..scenes.fill import fill_container
from ..scenes.liquid_level import fall_height as level_fall_height, impact_iterations as level_impact_iterations
from ..sim import (FluidModel, FluidState, QuadraticDrag, SDFGrid, UniformAcceleration, WallAdhesion, carve,
                   iterations_for_depth, make_state, solidify, step)

#: liquidtwin's model settings for generated scenes (what a server would use): at least this
#: many solver iterations, more for deep liquid (:func:`model_iterations`).
MODEL_ITERATIONS = 4
MODEL_RELAXATION = 4.0
#: The world solves its constraints more thoroughly than the model: this many more iterations,
#: with the cohesion of the model's count (``FluidModel.reference_iterations``; before stop 41
#: the world's per-step cohesion was (K + 2) / K times its λ_c, a stickier liquid than stated).
WORLD_EXTRA_ITERATIONS = 2


#: The fullest a benchmark fills a container (share of its capacity; × QUICK_FILL in quick scenes).
FULLEST = 0.9


def fill_depth(setup) -> float:
    """How deep (m, upright, flat surface) the liquid of ``setup``'s filled
    containers may be: each filled to :data:`FULLEST` of its capacity (× QUICK_FILL in quick
    scenes), or to its stated fill when that is more. Not the stated fill alone: the solver
    settings a recording states must not tell its analysis how full the source was."""
    from .catalog import QUICK_FILL
    depth = 0.0
    for name, ml in setup.fills:
        obj = setup.objects[setup.index(name)].model
        most = max(float(ml), FULLEST * obj.capacity_ml * (QUICK_FILL if setup.quick else 1.0))
        depth = max(depth, obj.height_for_volume(min(most, obj.capacity_ml)) - obj.floor_height)
    return depth


def model_iterations(setup) -> int:
    """Solver iterations of liquidtwin's model of ``setup``: :data:`MODEL_ITERATIONS`, or enough
    to hold its deepest liquid (:func:`fill_depth`) at rest (``sim.iterations_for_depth``:
    a 90 % full-size cup gets 6, a 90 % bottle 10)."""
    return iterations_for_depth(fill_depth(setup), 0.55 * setup.h, least=MODEL_ITERATIONS)


def model_for(setup) -> FluidModel:
    """liquidtwin's own model of a catalogue scene ``setup``: its objects, h and dt, the
    model's solver settings (:func:`model_iterations`) and default fluid parameters (what a
    server would run)."""
    return FluidModel.create(setup.h, dt=setup.dt, iterations=model_iterations(setup), relaxation=MODEL_RELAXATION,
                             objects=[o.grid for o in setup.objects])


def _falls(setup) -> tuple:
    """(poses at the start, object models, container indices): what the fall rules of
    ``scenes.liquid_level`` read from ``setup``."""
    return setup.poses_at(0.0), [o.model for o in setup.objects], [k for k, o in enumerate(setup.objects) if o.container]


def fall_height(setup) -> float:
    """The longest free fall (m) liquid can take in ``setup``: from the highest container rim
    down to the lowest container floor, the objects as they stand at the start (a cup that
    pours pivots about its lip, which stays about as high as the upright rim)."""
    return level_fall_height(*_falls(setup))


def impact_iterations(setup) -> int:
    """Solver iterations that take ``setup``'s fastest impact (free fall over
    :func:`fall_height`, ``sim.iterations_for_impact``) without throwing liquid back out,
    and at least :func:`model_iterations`: the quick catching scene 11 (a 32 cm fall), the
    plate 8, the pouring benchmark's cup 7."""
    return level_impact_iterations(*_falls(setup), setup.dt, 0.55 * setup.h, least=model_iterations(setup))


#: The control tasks' model moves a particle at most this many rest spacings per solver
#: iteration (``FluidModel.max_correction``): no drop bursts (README, "Bursting drops").
CONTROL_MAX_CORRECTION_SPACINGS = 0.5


def control_model(setup) -> FluidModel:
    """:func:`model_for`'s liquid solved with :func:`impact_iterations`: the model the control
    tasks (catching, the plate, pouring) plan with and are scored in, where what counts is
    where falling liquid lands. The cohesion stays that of :func:`model_iterations`
    (``reference_iterations``), so only how well the constraints are solved changes. At the
    model's 4 iterations the quick catching MPC lost 0.7-4.2 % of the liquid, thrown back out
    of the catcher faster than it fell in (README, "Solver iterations and impacts"). No
    iteration moves a particle more than :data:`CONTROL_MAX_CORRECTION_SPACINGS` spacings:
    without that cap, drops squeezed by their own fall burst and threw liquid out of the bowl
    (README, "Bursting drops"). Neighbour pairs that a wall separates are cut
    (``FluidModel.wall_pairs`` False): without that, the pour's last drops hung under the cup's
    base, held by the liquid inside it (README, "Cohesion through walls")."""
    m = FluidModel.create(setup.h, dt=setup.dt, iterations=impact_iterations(setup), relaxation=MODEL_RELAXATION,
                          objects=[o.grid for o in setup.objects], reference_iterations=model_iterations(setup))
    return m.replace(max_correction=CONTROL_MAX_CORRECTION_SPACINGS * m.spacing, wall_pairs=False)


@dataclass(frozen=True)
class World:
    """Everything needed to simulate the truth.

    Attributes:
      model: the world's FluidModel (objects possibly edited by the effect, extra terms).
      filler: the same world without the effect's terms and edits, used to settle the fill.
      fill_ml: {container: true initial volume, ml}; stated_ml: what the recording states.
      effects: the hidden effects (usually none or one).
    """

    model: FluidModel
    filler: FluidModel
    fill_ml: dict
    stated_ml: dict
    effects: tuple

    @property
    def params(self) -> dict:
        """The world's fluid parameters (floats, for the truth file)."""
        return self.model.params.as_dict()


def world_params(rng: np.random.Generator, defaults: dict) -> dict:
    """Fluid parameters of a real liquid: liquidtwin's defaults each jittered by ±5–15 %."""
    out = {}
    for k in ("lambda_c", "lambda_v"):
        sign = 1.0 if rng.random() < 0.5 else -1.0
        out[k] = float(defaults[k] * (1.0 + sign * rng.uniform(0.05, 0.15)))
    return out


def build_world(setup, effects, rng: np.random.Generator) -> World:
    """The world model for a scene ``setup`` (``generate.catalog.Setup``) and its hidden
    ``effects`` (a sequence of :class:`~.effects.Effect`, usually zero or one)."""
    objects = [o.grid for o in setup.objects]
    # More iterations, the model's cohesion: SPNets applies λ_c once per iteration, so two more
    # would make the world's liquid half again as sticky as its λ_c says (pbf.FluidModel).
    base = FluidModel.create(setup.h, dt=setup.dt, iterations=model_iterations(setup) + WORLD_EXTRA_ITERATIONS,
                             relaxation=MODEL_RELAXATION, objects=objects,
                             reference_iterations=model_iterations(setup))
    params = world_params(rng, base.params.as_dict())
    settle_params = dict(params)      # the fill settles without the effect's physics
    terms = []
    stated = dict(setup.fills)
    fill = dict(stated)
    for effect in effects:
        v = effect.value
        if effect.name == "drag":
            terms.append(QuadraticDrag(torch.tensor(v)))
        elif effect.name == "wind":
            az = math.radians(effect.extra["azimuth_deg"])
            terms.append(UniformAcceleration(torch.tensor([v * math.cos(az), 0.0, v * math.sin(az)])))
        elif effect.name == "viscosity":
            params["lambda_v"] = v
        elif effect.name == "cohesion":
            params["lambda_c"] = v
        elif effect.name == "wall_adhesion":
            terms.append(WallAdhesion(torch.tensor(v), base.spacing))
        elif effect.name == "leak":
            index, cut = setup.leak_site(v, effect.extra)
            objects[index] = carve(objects[index], cut)
        elif effect.name == "blockage":
            if setup.blockage_site is None:
                raise ValueError(f"scene {setup.name!r} has no spout or pipe leg that can be blocked")
            index, solid = setup.blockage_site(v, effect.extra)
            objects[index] = solid if isinstance(solid, SDFGrid) else solidify(objects[index], solid)
        elif effect.name == "fill_error":
            fill = {k: ml * (1.0 + v) for k, ml in fill.items()}
    model = base.replace(objects=tuple(objects), terms=tuple(terms)).with_params(**params)
    # Containers are filled and settled before the effect starts (a leak opens, wind rises).
    filler = base.with_params(**settle_params)
    return World(model, filler, fill, stated, tuple(effects))


def initial_state(world: World, setup, *, progress: bool = False):
    """Fill the scene's containers (true volumes) and settle; returns (state, fill reports).
    Containers filled with 0 ml stay empty; with no liquid at all the state has 0 particles."""
    poses = torch.as_tensor(setup.poses_at(0.0))
    reports = {}
    state = None
    for name, ml in world.fill_ml.items():
        if ml <= 0:
            continue
        index = setup.index(name)
        obj = setup.objects[index].model
        s, report = fill_container(world.filler, poses, index, obj, volume_ml=ml, progress=progress,
                                   settle_s=0.5 if setup.quick else 1.0)
        reports[name] = report
        state = s if state is None else _merge(state, s)
    if state is None:
        if not world.fill_ml:
            raise ValueError(f"scene {setup.name!r} has no liquid")
        empty = torch.zeros(0, 3)
        state = FluidState(empty, empty.clone(), torch.zeros(0, dtype=torch.long), poses.to(torch.float32))
    return state, reports


def _merge(a, b):
    (xa, va), (xb, vb) = a.by_id(), b.by_id()
    return make_state(torch.cat([xa, xb]), torch.cat([va, vb]), poses=a.poses, dtype=a.x.dtype, t=a.t)


def simulate(world: World, setup, state, steps: int, *, progress: bool = False) -> np.ndarray:
    """Run the world; returns particle positions by id before each step and after the
    last: (steps + 1, N, 3) float32, m (row k is time k·dt)."""
    out = np.empty((steps + 1,) + tuple(state.x.shape), np.float32)
    out[0] = state.by_id()[0].detach().numpy()
    if state.x.shape[0] == 0:                 # an empty scene: nothing moves
        return out
    bar = tqdm(total=steps, desc=f"world {setup.name}", unit="step", disable=not progress, leave=False)
    with torch.no_grad():
        for k in range(steps):
            poses = torch.as_tensor(setup.poses_at((k + 1) * setup.dt), dtype=state.x.dtype)
            state = step(world.model, state, poses)
            out[k + 1] = state.by_id()[0].numpy()
            bar.update()
    bar.close()
    return out
