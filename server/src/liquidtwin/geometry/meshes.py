"""The model catalogue: a registry of procedural objects, the pipe junction and scene layouts.

``build("mug", radius=0.04)`` makes any catalogue model by name with keyword parameters (SI
units, realistic defaults); ``MODELS`` maps names to builders. Layouts return lists of
(ObjectModel, pose) with poses (7,) float64 (tx, ty, tz, qx, qy, qz, qw), object → world.
"""

from __future__ import annotations

import dataclasses
import inspect
import math

import numpy as np

from . import models
from ._build import boxes_mesh
from .object_model import ObjectModel

BLOCKAGES = {"none": 0.0, "partial": None, "full": 1.0}


def _blocked_fraction(name: str, value, partial_fraction: float) -> float:
    """'none' | 'partial' | 'full' or a number in [0, 1] → blocked fraction of the leg height."""
    if isinstance(value, str):
        if value not in BLOCKAGES:
            raise ValueError(f"pipe_junction: {name} must be one of {sorted(BLOCKAGES)} or a "
                             f"fraction in [0, 1], got {value!r}")
        return partial_fraction if BLOCKAGES[value] is None else BLOCKAGES[value]
    value = float(value)
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"pipe_junction: {name} as a number is the blocked fraction in [0, 1], "
                         f"got {value}")
    return value


def pipe_junction(inner: float = 0.03, wall: float = 0.003, arm: float = 0.12, stem: float = 0.08,
                  drop: float = 0.05, left="none", right="none", partial_fraction: float = 0.6,
                  plug_offset: float = 0.06, plug_length: float = 0.012) -> ObjectModel:
    """Inverted T-junction of square ducts (thesis ch. 7.4), fed from above.

    A vertical inlet (``inner`` m square inside, ``stem`` m tall, open at the top) meets a
    horizontal crossbar along x; each end (``arm`` m from the centre, at −x "left" and +x
    "right") turns down into a ``drop`` m leg open at y = 0. A blockage is a plug
    ``plug_length`` m long, ``plug_offset`` m from the centre inside a horizontal leg:
    ``'full'`` closes it, ``'partial'`` fills the lower ``partial_fraction`` of its height
    (liquid must rise over it), a number in [0, 1] gives that fraction directly.
    Anchors: ``inlet`` (top opening centre), ``left_outlet``, ``right_outlet``.
    """
    models._check("pipe_junction", inner=inner, wall=wall, arm=arm, stem=stem, drop=drop,
                  plug_length=plug_length, plug_offset=plug_offset)
    a = inner / 2
    if not (a + plug_length / 2 < plug_offset < arm - inner - plug_length / 2):
        raise ValueError(f"pipe_junction: plug_offset must put the plug between the inlet and the "
                         f"down leg: {a + plug_length / 2:.3f} < plug_offset < "
                         f"{arm - inner - plug_length / 2:.3f} m")
    fractions = {side: _blocked_fraction(side, v, partial_fraction)
                 for side, v in (("left", left), ("right", right))}
    yc = drop + a                                   # crossbar centre line height
    top = yc + a + stem
    e = 2 * wall                                    # how far open ends poke through
    channels = [((-arm, yc - a, -a), (arm, yc + a, a)),                 # crossbar
                ((-a, yc - a, -a), (a, top + e, a)),                     # inlet stem
                ((-arm, -e, -a), (-arm + inner, yc + a, a)),             # left leg
                ((arm - inner, -e, -a), (arm, yc + a, a))]               # right leg
    boxes = []
    for lo, hi in channels:                        # walls: channels grown by the wall thickness
        lo, hi = np.array(lo, float) - wall, np.array(hi, float) + wall
        lo[1], hi[1] = max(lo[1], 0.0), min(hi[1], top)
        boxes.append((lo, hi, True))
    boxes += [(np.array(lo, float), np.array(hi, float), False) for lo, hi in channels]
    for side, sign in (("left", -1.0), ("right", 1.0)):
        f = fractions[side]
        if f > 0:
            x0 = sign * plug_offset - plug_length / 2
            top_y = yc - a + f * inner + (wall / 2 if f >= 1 else 0.0)
            boxes.append((np.array([x0, yc - a - wall / 2, -a - wall / 2]),
                          np.array([x0 + plug_length, top_y, a + wall / 2]), True))
    mesh = boxes_mesh(boxes, "pipe_junction")
    anchors = {"inlet": [0.0, top, 0.0], "left_outlet": [-arm + a, 0.0, 0.0],
               "right_outlet": [arm - a, 0.0, 0.0]}
    return ObjectModel("pipe_junction", mesh, float(wall), None, None, anchors)


MODELS = {
    "cup": models.cup, "bottle": models.bottle, "mug": models.mug, "bowl": models.bowl,
    "fruit_bowl": models.fruit_bowl, "dog_dish": models.dog_dish, "pan": models.pan,
    "plate": models.plate, "ladle": models.ladle, "basin": models.basin,
    "pipe_junction": pipe_junction,
}
"""Catalogue model name → builder taking keyword parameters (SI units)."""


def model_params(name: str) -> dict:
    """Parameter names of a catalogue model with their defaults."""
    return {k: p.default for k, p in inspect.signature(_builder(name)).parameters.items()}


def _builder(name: str):
    if name not in MODELS:
        raise ValueError(f"unknown object model {name!r}; known models: "
                         f"{', '.join(sorted(MODELS))}")
    return MODELS[name]


def build(name: str, **params) -> ObjectModel:
    """Build catalogue model ``name`` with keyword ``params`` (unknown names → ValueError)."""
    fn = _builder(name)
    known = model_params(name)
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise ValueError(f"model {name!r} has no parameter(s) {unknown}; it takes {sorted(known)}")
    return fn(**params)


def _pose(x=0.0, y=0.0, z=0.0) -> np.ndarray:
    return np.array([x, y, z, 0.0, 0.0, 0.0, 1.0])


def plate_with_bowls(n_bowls: int = 8, ring_radius: float = 0.25, plate_height: float = 0.12,
                     plate: dict | None = None, bowl: dict | None = None) -> list:
    """The plate scene (thesis §8.3): a plate raised ``plate_height`` m above the table,
    centred on the world origin, and ``n_bowls`` bowls on the table on a circle of
    ``ring_radius`` m around it (bowl k at angle 2πk/n from +x towards +z).

    Returns:
      [(plate, pose), (bowl_0, pose), …], poses (7,) float64.
    """
    if n_bowls < 1:
        raise ValueError(f"n_bowls must be >= 1, got {n_bowls}")
    p = build("plate", **(plate or {}))
    b = build("bowl", **{"radius": 0.06, "depth": 0.05, "base_radius": 0.03, **(bowl or {})})
    outer = float(b.mesh.bounds[1, 0])
    if 2 * ring_radius * math.sin(math.pi / n_bowls) < 2 * outer and n_bowls > 1:
        raise ValueError(f"{n_bowls} bowls {2 * outer:.3f} m wide do not fit on a circle of "
                         f"radius {ring_radius} m")
    below_plate = ring_radius - outer < float(p.mesh.bounds[1, 0])
    if below_plate and plate_height < float(b.mesh.bounds[1, 1]):
        raise ValueError("the bowls overlap the plate: raise plate_height or ring_radius")
    out = [(p, _pose(y=plate_height))]
    for k in range(n_bowls):
        t = 2 * math.pi * k / n_bowls
        out.append((dataclasses.replace(b, name=f"bowl_{k}"),
                    _pose(ring_radius * math.cos(t), 0.0, ring_radius * math.sin(t))))
    return out


def catching_cups(height: float = 0.3, offset: float = 0.12, source: dict | None = None,
                  target: dict | None = None) -> list:
    """The catching scene (thesis §8.3): a pouring cup held upright ``height`` m above the
    table at the world origin and a catching cup on the table ``offset`` m along −x (the
    side the source pours to).

    Returns:
      [(source_cup, pose), (catching_cup, pose)], poses (7,) float64.
    """
    src = dataclasses.replace(build("cup", **(source or {})), name="source_cup")
    dst = dataclasses.replace(build("cup", **(target or {})), name="catching_cup")
    if height < float(dst.mesh.bounds[1, 1]) + 0.01:
        raise ValueError(f"height {height} m puts the source cup inside the catching cup")
    return [(src, _pose(y=height)), (dst, _pose(x=-offset))]
