"""Build a session's scene from its spec the way the generator builds liquidtwin's model.

Objects come from :func:`liquidtwin.scenes.spec.scene_objects`; their SDF grids are the
catalogue models' own (``ObjectModel.sdf()``) and, for the table, the analytic slab the
generator uses (:func:`liquidtwin.scenes.pour.floor_grid`). The :class:`FluidModel` takes the
spec's simulation settings, liquidtwin's model relaxation (``generate.world.MODEL_RELAXATION``)
and the default fluid parameters overridden by ``spec.fluid``. Containers are filled and
settled with :func:`liquidtwin.scenes.fill.fill_container`, as the generator fills its world.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..generate.world import MODEL_RELAXATION
from ..geometry import MeshError, ObjectModel
from ..scenes.fill import fill_container
from ..scenes.pour import floor_grid
from ..scenes.spec import TABLE_MODEL, SpecError, scene_objects, simulation_settings
from ..sim import FluidModel, FluidState, iterations_for_depth, make_state
from .errors import BAD_REQUEST, INFEASIBLE, EngineError

#: Simulated settling time of a fill, s (the generator's quick scenes use the same).
SETTLE_S = 0.5
_FLUID_FIELDS = ("lambda_c", "lambda_v", "lambda_s", "lambda_omega")


@dataclass(frozen=True, eq=False)
class Scene:
    """A built scene.

    Attributes:
      names: object names, in the spec's order (the model's object order).
      objects: their :class:`ObjectModel` s.
      containers: names of the container objects.
      occluders: indices of objects that hide liquid from cameras (all but tables, which
        lie under the liquid and the cameras, as in the generator).
      initial_poses: (M, 7) float64 poses the fill was made at.
      model: the session's :class:`FluidModel` (on the session's device).
      state: the settled initial fill (on the session's device).
      fills: {container: FillReport}.
      ml_per_particle: settled ml per particle over all fills.
    """

    names: tuple
    objects: tuple
    containers: tuple
    occluders: tuple
    initial_poses: np.ndarray
    model: FluidModel
    state: FluidState
    fills: dict
    ml_per_particle: float


def fluid_params(spec: pb.SessionSpec) -> tuple[dict, float]:
    """(fluid parameter overrides, relaxation) from ``spec.fluid``; checks they are finite."""
    params, relaxation = {}, MODEL_RELAXATION
    for k in _FLUID_FIELDS + ("relaxation",):
        if spec.fluid.HasField(k):
            v = float(getattr(spec.fluid, k))
            if not np.isfinite(v) or v < 0:
                raise EngineError(BAD_REQUEST, f"fluid.{k} must be a finite number >= 0, got {v}")
            if k == "relaxation":
                relaxation = v
            else:
                params[k] = v
    return params, relaxation


def _grid(name: str, model_name: str, obj: ObjectModel):
    if model_name == TABLE_MODEL:
        return floor_grid()
    try:
        return obj.sdf()
    except (ValueError, MeshError) as exc:
        raise EngineError(BAD_REQUEST, f"object {name!r}: cannot build its signed distance grid: {exc}") from None


def build_scene(spec: pb.SessionSpec, *, device: str = "cpu", progress: bool = False, base_dir=".") -> Scene:
    """Objects, model and settled fill of ``spec.scene`` (module doc); EngineError on failure."""
    scene = spec.scene
    try:
        items = scene_objects(scene, base_dir=base_dir)
    except (SpecError, MeshError) as exc:
        raise EngineError(BAD_REQUEST, f"scene: {exc}") from None
    except OSError as exc:
        raise EngineError(BAD_REQUEST, f"scene: cannot read a mesh: {exc}") from None
    sim = simulation_settings(scene)
    if not (sim["h"] > 0 and sim["dt"] > 0 and sim["spacing"] > 0):
        raise EngineError(BAD_REQUEST, f"scene.simulation: h, dt and spacing must be > 0, got {sim}")
    params, relaxation = fluid_params(spec)
    names = tuple(n for n, _, _ in items)
    objects = tuple(o for _, o, _ in items)
    model_names = [o.model for o in scene.objects]
    grids = [_grid(n, m, o) for (n, o, _), m in zip(items, model_names)]
    poses = np.stack([p for _, _, p in items])
    try:
        model = FluidModel.create(sim["h"], spacing=sim["spacing"], dt=sim["dt"], iterations=int(sim["iterations"]),
                                  relaxation=relaxation, objects=grids, params=params,
                                  reference_iterations=sim["reference_iterations"],
                                  max_correction=None if sim["max_correction_spacings"] is None
                                  else sim["max_correction_spacings"] * sim["spacing"],
                                  wall_pairs=not sim["cut_wall_pairs"])
    except ValueError as exc:
        raise EngineError(BAD_REQUEST, f"fluid model: {exc}") from None
    state, fills = _fill(model, scene, names, objects, poses, progress)
    ml = sum(r.settled_ml for r in fills.values())
    count = sum(r.particles for r in fills.values())
    if device != "cpu":
        model = model.replace(objects=tuple(g.to(device=device) for g in model.objects),
                              params=model.params.to(device=device))
        state = make_state(state.x, state.v, state.poses, dtype=state.x.dtype, device=device)
    containers = tuple(n for n, o in zip(names, scene.objects) if o.container)
    occluders = tuple(k for k, m in enumerate(model_names) if m != TABLE_MODEL)
    return Scene(names, objects, containers, occluders, poses, model, state, fills, ml / count)


def _fill(model, scene, names, objects, poses, progress) -> tuple[FluidState, dict]:
    if not len(scene.fills):
        raise EngineError(BAD_REQUEST, "scene has no fills: a session needs liquid in at least one container")
    tp = torch.as_tensor(poses)
    x, v, fills = [], [], {}
    for f in scene.fills:
        if f.container in fills:
            raise EngineError(BAD_REQUEST, f"container {f.container!r} is filled twice")
        k = names.index(f.container)
        amount = {f.WhichOneof("amount"): getattr(f, f.WhichOneof("amount"))}
        try:
            s, report = fill_container(model, tp, k, objects[k], settle_s=SETTLE_S, progress=progress, **amount)
        except ValueError as exc:
            raise EngineError(INFEASIBLE, f"cannot fill {f.container!r}: {exc}") from None
        need = iterations_for_depth(report.height_m - objects[k].floor_height, model.spacing)
        if model.iterations < need:
            warnings.warn(f"{f.container!r}: its liquid is {100 * (report.height_m - objects[k].floor_height):.1f} cm "
                          f"deep, more than {model.iterations} solver iterations hold at rest (it will bounce and "
                          f"boil over); scene.simulation.iterations >= {need} holds it", RuntimeWarning, stacklevel=2)
        xs, vs = s.by_id()
        x.append(xs)
        v.append(vs)
        fills[f.container] = report
    state = make_state(torch.cat(x), torch.cat(v), poses=tp, dtype=torch.float32)
    return state, fills
