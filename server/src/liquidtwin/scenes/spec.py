"""Scene specs: the small description of a scene that recordings carry and the server accepts.

A spec is the protobuf message ``liquidtwin.v1.SceneSpec`` (proto/…/liquidtwin.proto); as a
file it is that message's canonical protobuf JSON, so one definition serves the wire, the
MCAP ``/scene`` topic and hand-written files::

    {"name": "my_pour",
     "objects": [{"name": "source", "model": "cup", "container": true,
                  "initialPose": [0.1, 0.2, 0, 0, 0, 0, 1]},
                 {"name": "target", "model": "mesh", "meshUri": "meshes/bowl.stl",
                  "params": {"scale": 0.001}, "container": true}],
     "fills": [{"container": "source", "volumeMl": 150}],
     "simulation": {"h": 0.011, "dt": 0.008333}}

:func:`scene_objects` turns a spec into :class:`~liquidtwin.geometry.ObjectModel` s: a
catalogue model with its parameters, or a user mesh (``model: "mesh"``) loaded from
``mesh_uri`` (relative to the spec file), checked against ``mesh_sha256`` when given, scaled
by ``params["scale"]`` and, when ``container`` is true, analysed for its cavity.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import trimesh
from google.protobuf import json_format
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..geometry import MODELS, build, container_from_mesh, load_mesh
from ..geometry.object_model import ObjectModel

#: The table under a scene: a 90 cm slab whose top face is y = 0 (model name ``"table"``).
TABLE_MODEL = "table"
TABLE_SIZE = (0.9, 0.04, 0.9)

#: Simulation settings used when a spec leaves them at zero.
DEFAULT_SIMULATION = {"h": 0.011, "dt": 1.0 / 120.0, "iterations": 4}


class SpecError(ValueError):
    """A scene spec that cannot be used; the message names the field."""


def load_spec(path) -> pb.SceneSpec:
    """Read a SceneSpec from a protobuf-JSON file (unknown fields are errors)."""
    path = Path(path)
    try:
        spec = json_format.Parse(path.read_text(), pb.SceneSpec())
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(f"{path}: cannot read scene spec: {exc}") from None
    except json_format.ParseError as exc:
        raise SpecError(f"{path}: not a valid SceneSpec JSON: {exc}") from None
    check_spec(spec, source=str(path))
    return spec


def save_spec(spec: pb.SceneSpec, path) -> None:
    """Write a SceneSpec as protobuf JSON (stable field order, 2-space indent)."""
    Path(path).write_text(json_format.MessageToJson(spec, indent=2, sort_keys=True) + "\n")


def check_spec(spec: pb.SceneSpec, source: str = "scene spec") -> None:
    """Raise :class:`SpecError` for duplicate/empty names, unknown models, bad poses,
    fills of unknown or non-container objects, and negative settings."""
    names = [o.name for o in spec.objects]
    if not names:
        raise SpecError(f"{source}: no objects")
    if len(set(names)) != len(names) or "" in names:
        raise SpecError(f"{source}: object names must be unique and non-empty, got {names}")
    for o in spec.objects:
        if o.model not in ("mesh", TABLE_MODEL) and o.model not in MODELS:
            raise SpecError(f"{source}: object {o.name!r}: unknown model {o.model!r}; "
                            f"use 'mesh', 'table' or one of {', '.join(MODELS)}")
        if o.model == "mesh" and not o.mesh_uri:
            raise SpecError(f"{source}: object {o.name!r}: model 'mesh' needs mesh_uri")
        pose = list(o.initial_pose)
        if pose and (len(pose) != 7 or not all(math.isfinite(a) for a in pose)
                     or abs(np.linalg.norm(pose[3:]) - 1.0) > 1e-3):
            raise SpecError(f"{source}: object {o.name!r}: initial_pose must be 7 finite numbers "
                            f"(tx ty tz qx qy qz qw) with a unit quaternion")
    containers = {o.name for o in spec.objects if o.container}
    for f in spec.fills:
        if f.container not in containers:
            raise SpecError(f"{source}: fill of {f.container!r}, which is not a container object")
        amount = f.WhichOneof("amount")
        value = getattr(f, amount) if amount else None
        if value is None or not value > 0 or (amount == "fraction" and value > 1):
            raise SpecError(f"{source}: fill of {f.container!r} needs volume_ml > 0 or fraction in (0, 1]")
    sim = spec.simulation
    if sim.h < 0 or sim.dt < 0 or sim.spacing < 0:
        raise SpecError(f"{source}: simulation h, dt and spacing must be >= 0 (0 = default)")


def solve_with(spec: pb.SceneSpec, iterations: int) -> pb.SceneSpec:
    """``spec`` (changed in place, and returned) solving ``iterations`` constraint iterations a
    step for the *same* liquid: cohesion stays what the stated count applies
    (``simulation.reference_iterations``), so only how well the constraints are solved changes.
    ValueError unless ``iterations`` is a whole number >= 1 (the spec is then unchanged)."""
    if isinstance(iterations, bool) or not isinstance(iterations, (int, float)) or iterations < 1 \
            or int(iterations) != iterations:
        raise ValueError(f"solver iterations must be a whole number >= 1, got {iterations!r}")
    sim = simulation_settings(spec)
    spec.simulation.reference_iterations = int(sim["reference_iterations"] or sim["iterations"])
    spec.simulation.iterations = int(iterations)
    return spec


def simulation_settings(spec: pb.SceneSpec) -> dict:
    """{h, dt, iterations, spacing, reference_iterations, max_correction_spacings,
    cut_wall_pairs} with the defaults filled in (reference_iterations None: SPNets' cohesion,
    in full every iteration; max_correction_spacings None: no cap on a solver iteration's
    move; cut_wall_pairs False: pairs interact through walls, as SPNets)."""
    s = spec.simulation
    h = s.h or DEFAULT_SIMULATION["h"]
    return {"h": h, "dt": s.dt or DEFAULT_SIMULATION["dt"],
            "iterations": s.iterations or DEFAULT_SIMULATION["iterations"], "spacing": s.spacing or 0.55 * h,
            "reference_iterations": s.reference_iterations or None,
            "max_correction_spacings": s.max_correction_spacings or None, "cut_wall_pairs": bool(s.cut_wall_pairs)}


def _mesh_object(o: pb.SceneObject, base: Path) -> ObjectModel:
    path = Path(o.mesh_uri.removeprefix("file://"))
    path = path if path.is_absolute() else base / path
    if o.mesh_sha256:
        try:
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
        except OSError as exc:
            raise SpecError(f"object {o.name!r}: cannot read mesh {path}: {exc}") from None
        if digest != o.mesh_sha256.lower():
            raise SpecError(f"object {o.name!r}: mesh {path} has SHA-256 {digest}, the spec says {o.mesh_sha256}")
    params = dict(o.params)
    unknown = set(params) - {"scale", "wall"}
    if unknown:
        raise SpecError(f"object {o.name!r}: mesh objects take params 'scale' and 'wall', not {sorted(unknown)}")
    mesh = load_mesh(path, scale=params.get("scale", 1.0))
    if o.container:
        return container_from_mesh(mesh, o.name, wall=params.get("wall"))
    wall = params.get("wall")
    if wall is None:
        raise SpecError(f"object {o.name!r}: a mesh that is not a container needs params.wall (m)")
    return ObjectModel(o.name, mesh, wall)


def impact_iterations(spec: pb.SceneSpec, base_dir=".") -> int:
    """Solver iterations that solve the impacts of ``spec``'s scene: enough for liquid falling
    from its highest container rim to its lowest container floor, the objects at their initial
    poses (``liquid_level.impact_iterations``), and at least the count it states. Give it to
    :func:`solve_with` to keep the same liquid."""
    from .liquid_level import impact_iterations as need
    objects = scene_objects(spec, base_dir)
    sim = simulation_settings(spec)
    return need(np.stack([pose for _, _, pose in objects]), [m for _, m, _ in objects],
                [k for k, o in enumerate(spec.objects) if o.container], sim["dt"], sim["spacing"],
                least=sim["iterations"])


def scene_objects(spec: pb.SceneSpec, base_dir=".") -> list[tuple[str, ObjectModel, np.ndarray]]:
    """(name, ObjectModel, initial pose (7,)) per object; ``base_dir`` resolves relative
    mesh paths. Raises :class:`SpecError` (or the geometry's ``MeshError``) clearly."""
    check_spec(spec)
    out = []
    for o in spec.objects:
        if o.model == "mesh":
            model = _mesh_object(o, Path(base_dir))
        elif o.model == TABLE_MODEL:
            slab = trimesh.creation.box(extents=TABLE_SIZE)
            slab.apply_translation([0.0, -0.5 * TABLE_SIZE[1], 0.0])
            model = ObjectModel(o.name, slab, 0.5 * TABLE_SIZE[1])
        else:
            try:
                model = build(o.model, **dict(o.params))
            except (TypeError, ValueError) as exc:
                raise SpecError(f"object {o.name!r}: {exc}") from None
        pose = np.asarray(list(o.initial_pose) or [0, 0, 0, 0, 0, 0, 1.0], float)
        out.append((o.name, model, pose))
    return out
