"""Named scenes for the generator: objects, their scripted motions, fills and cameras.

Every scene is randomised by the seed within the thesis's protocol (which source and target
container, how full, where the camera stands) and has a ``quick`` variant — the same scene
sped up and shortened — for tests. Containers come from ``geometry.meshes`` at real sizes;
the table is an analytic slab (``scenes.pour.floor_grid``) under everything.

Scenes: ``pour_partial``, ``pour_hold``, ``pour_dump`` (ch. 4.2.1), ``catching`` (a cup
slides under a stream, ch. 8.3), ``pipe`` (a tilting cup feeds a T-junction, ch. 7.4),
``plate_tilt`` (a plate tilts liquid into one of 8 bowls, ch. 8.3) and ``ladle`` (scoop from a
basin, pour into a bowl, ch. 8.3).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..camera import Camera
from ..geometry import build, model_params
from ..scenes import motions as mo
from ..scenes import shapes
from ..scenes.pour import floor_grid
from ..sim import SDFGrid, cylinder_sdf

H = 0.011              # kernel radius, m (rest spacing 0.55 h ≈ 6 mm)
DT = 1.0 / 120.0       # s
TABLE = "table"
#: Quick variants hold this fraction of the full scene's liquid (a few hundred particles).
QUICK_FILL = 0.2
#: How far beyond a tilted cup's lip its stream lands 10–15 cm lower, m (measured on generated pours at both speeds).
STREAM_REACH = 0.085
#: The pipe scene's junction: 4.5 cm square ducts, legs 27.5 cm apart (over the two bowls).
PIPE = {"inner": 0.045, "arm": 0.16}
#: Gap between the pipe's leg openings and the taller bowl's rim, m.
PIPE_CLEARANCE = 0.03
#: The pipe's feeding cup: lip 5 cm beside the inlet's centre line and 5 cm above its top (the
#: cup's base then clears the crossbar below it by 1.7 cm), tilted at twice the thesis pour's
#: rate, 90 % full, so that the flow backs up over a partial plug. Where its stream lands was
#: measured on generated pipe scenes (``bench/pipe_scene.py``: the share entering the inlet).
PIPE_LIP_X, PIPE_LIP_ABOVE, PIPE_POUR_SPEED, PIPE_FILL = 0.05, 0.05, 2.0, 0.9
#: The pipe scene's camera: a robot's head camera 55 cm above the table and 45 cm in front,
#: looking down (~50°) at a point 10 cm below the leg openings, so that it sees into both bowls
#: (thesis §7.4.3: the legs "emptied into different bowls, both visible to the robot"). From
#: 30 cm up (the first rig) it saw the bowls' outsides and only a sliver of their liquid.
PIPE_EYE, PIPE_LOOK_BELOW = (0.0, 0.55, 0.45), 0.10


@dataclass(frozen=True, eq=False)
class SceneItem:
    """One object: ``name``, catalogue ``model_name`` and ``params``, the built ObjectModel
    (None for the table), its SDF ``grid``, its ``motion`` (t → (7,) pose) and whether it is
    a ``container`` whose liquid is reported."""

    name: str
    model_name: str
    params: dict
    model: object
    grid: SDFGrid
    motion: Callable
    container: bool = False


@dataclass(frozen=True, eq=False)
class Setup:
    """A scene ready to simulate. ``fills``: ((container name, stated ml), …). ``leak_site``
    and ``blockage_site`` map an effect's (value, extra) to (object index, solid SDF fn or a
    replacement SDFGrid); None when the scene has no such place."""

    name: str
    objects: tuple
    fills: tuple
    cameras: tuple
    duration: float
    motion: str
    motion_params: dict
    h: float = H
    dt: float = DT
    leak_site: Callable | None = None
    blockage_site: Callable | None = None
    notes: dict = field(default_factory=dict)
    quick: bool = False

    def index(self, name: str) -> int:
        for k, o in enumerate(self.objects):
            if o.name == name:
                return k
        raise KeyError(f"scene {self.name!r} has no object {name!r}")

    def poses_at(self, t: float) -> np.ndarray:
        """(M, 7) float64 object poses at time t, s."""
        return np.stack([o.motion(t) for o in self.objects])

    @property
    def names(self) -> tuple:
        return tuple(o.name for o in self.objects)


def _item(name, model_name, motion, container=False, **params) -> SceneItem:
    model = build(model_name, **params)
    return SceneItem(name, model_name, params, model, model.sdf(), motion, container)


def _table() -> SceneItem:
    return SceneItem(TABLE, "table", {}, None, floor_grid(), mo.Static(), False)


def _camera(rng, eye, target, quick: bool, name: str = "thermal") -> Camera:
    eye = np.asarray(eye, float) + rng.uniform(-0.03, 0.03, 3)
    target = np.asarray(target, float) + rng.uniform(-0.01, 0.01, 3)
    w, h = (320, 240) if quick else (640, 480)
    return Camera.look_at(eye, target, width=w, height=h, fov_y_deg=float(rng.uniform(42.0, 50.0)), name=name)


def _radial(model, y: float) -> tuple[float, float]:
    """(inner, outer) radius of a round container at height y (object frame), m."""
    v = np.asarray(model.mesh.vertices)
    near = np.abs(v[:, 1] - y) < 0.01
    outer = float(np.linalg.norm(v[near][:, [0, 2]], axis=1).max()) if near.any() else float(
        np.linalg.norm(v[:, [0, 2]], axis=1).max())
    cv = np.asarray(model.cavity.vertices)
    near = np.abs(cv[:, 1] - y) < 0.01
    inner = float(np.linalg.norm(cv[near][:, [0, 2]], axis=1).max()) if near.any() else outer - model.wall
    return inner, outer


def _lip(model) -> np.ndarray:
    if getattr(model, "lip", None) is not None:
        return np.asarray(model.lip, float)
    top = float(model.cavity.bounds[1][1])
    _, outer = _radial(model, top)
    return np.array([-outer, top, 0.0])


def source_sites(index: int, model, fill_ml: float):
    """Leak (a radial hole through the wall, below the initial liquid surface) and blockage
    (a plate across the opening on the pouring side) of a round source container in its own
    frame."""
    lo, hi = model.cavity.bounds
    depth = float(model.height_for_volume(fill_ml)) - float(lo[1])

    def leak(radius, extra):
        y = float(lo[1]) + max(extra["height_fraction"] * depth, radius + model.wall)
        inner, outer = _radial(model, y)
        az = math.radians(extra["azimuth_deg"])
        axis = np.array([math.cos(az), 0.0, math.sin(az)])
        centre = 0.5 * (inner + outer) * axis + np.array([0.0, y, 0.0])
        return index, cylinder_sdf(centre, axis, radius, 0.5 * (outer - inner) + 0.004)

    def blockage(fraction, extra):
        top = float(hi[1])
        inner, _ = _radial(model, top - 0.004)
        reach = -inner + 2.0 * inner * min(fraction, 1.0)        # plate spans x ∈ [−inner − wall, reach]
        x0 = -inner - model.wall
        half = np.array([0.5 * (reach - x0), 0.002, inner + model.wall])
        centre = np.array([0.5 * (reach + x0), top - 0.006, 0.0])
        return index, lambda p: shapes.box(p, half, centre)

    return leak, blockage


SOURCES = ("cup", "bottle", "mug")
TARGETS = ("bowl", "fruit_bowl", "dog_dish", "pan")
FRACTIONS = (0.3, 0.6, 0.9)


def scaled_params(model_name: str, scale: float) -> dict:
    """Parameters of catalogue model ``model_name`` with every length but the wall × ``scale``
    (the same shape, larger or smaller; walls keep their thickness so collisions stay as safe)."""
    if not (math.isfinite(scale) and 0.0 < scale <= 1.0):
        raise ValueError(f"source_scale must be in (0, 1], got {scale}")
    if scale == 1.0:
        return {}
    return {k: v * scale for k, v in model_params(model_name).items() if k != "wall"}


def _pour(kind: str, rng, quick: bool, source: str | None = None, target: str | None = None,
          fraction: float | None = None, source_scale: float | None = None) -> Setup:
    # Always draw, then override: a chosen source leaves every other draw of the seed unchanged.
    source_name = str(rng.choice(SOURCES))
    target_name = str(rng.choice(TARGETS))
    drawn = float(rng.choice(FRACTIONS))
    source_name = source or source_name
    target_name = target or target_name
    fraction = drawn if fraction is None else float(fraction)
    target = _item("target", target_name, mo.Static(), container=True)
    src_params = scaled_params(source_name, 1.0 if source_scale is None else float(source_scale))
    src_model = build(source_name, **src_params)
    t_lo, t_hi = target.model.cavity.bounds
    r_t = 0.5 * float(t_hi[0] - t_lo[0])
    rim_t = float(target.model.mesh.bounds[1][1])
    lip_local = _lip(src_model)
    lip_world = np.array([0.3 * r_t, rim_t + 0.015 + lip_local[1], 0.0])
    speed = 2.5 if quick else 1.0
    motion = mo.pour(kind, lip_local, lip_world, start=0.3 if quick else 0.5, speed=speed)
    source = SceneItem("source", source_name, src_params, src_model, src_model.sdf(), motion, True)
    volume = round(fraction * src_model.capacity_ml * (QUICK_FILL if quick else 1.0), 1)
    leak, blockage = source_sites(0, src_model, volume)
    centre = np.array([0.05, 0.5 * (rim_t + lip_world[1]), 0.0])
    # Raised ~35° like the thesis's tripod camera, so it sees into the target, not just its wall.
    cam = _camera(rng, centre + np.array([0.0, 0.36, 0.5]), centre, quick)
    duration = motion.end + (0.6 if quick else 1.5)
    return Setup(f"pour_{kind}", (source, target, _table()), (("source", volume),), (cam,), duration,
                 "pour", {"kind_" + kind: 1.0, "speed": speed}, leak_site=leak, blockage_site=blockage,
                 notes={"source": source_name, "target": target_name, "fraction": fraction})


def _catching(rng, quick: bool) -> Setup:
    src_model = build("cup")
    lip_local = _lip(src_model)
    lip_world = np.array([0.0, 0.32, 0.0])
    speed = 2.0 if quick else 1.0
    motion = mo.pour("hold", lip_local, lip_world, start=0.3, speed=speed)
    source = SceneItem("source", "cup", {}, src_model, src_model.sdf(), motion, True)
    # The stream leaves the lip sideways and lands ~8.5 cm beyond it (measured at both speeds).
    x_catch = lip_world[0] - STREAM_REACH - float(rng.uniform(0.0, 0.01))
    start_x = x_catch + float(rng.choice([-1.0, 1.0])) * float(rng.uniform(0.12, 0.18))
    slide = mo.slide([start_x, 0.0, 0.0], [x_catch, 0.0, 0.0], start=0.2, duration=(1.0 if quick else 2.0))
    catcher = _item("catcher", "cup", slide, container=True)
    volume = round(0.6 * src_model.capacity_ml * (QUICK_FILL if quick else 1.0), 1)
    leak, blockage = source_sites(0, src_model, volume)
    cam = _camera(rng, [0.0, 0.3, 0.85], [0.0, 0.2, 0.0], quick)
    duration = motion.end + (1.0 if quick else 2.5)
    return Setup("catching", (source, catcher, _table()), (("source", volume),), (cam,), duration, "catching",
                 {"speed": speed}, leak_site=leak, blockage_site=blockage)


def _pipe(rng, quick: bool) -> Setup:
    """Thesis §7.4.3: a cup poured steadily into the top of an inverted T-junction held
    above two bowls, one under each leg; the camera looks at the junction, the streams from
    its legs and the bowls (the liquid inside the opaque pipe is hidden). A plug in a leg
    (the ``blockage`` effect) sends the liquid into the other bowl (full), or lets through
    only what backs up over it (partial). The camera looks down into the bowls (``PIPE_EYE``)."""
    y_pipe = float(build("fruit_bowl").mesh.bounds[1][1]) + PIPE_CLEARANCE
    pipe = _item("pipe", "pipe_junction", mo.Static((0.0, y_pipe, 0.0, 0.0, 0.0, 0.0, 1.0)), **PIPE)
    leg = PIPE["arm"] - 0.5 * PIPE["inner"]          # leg centre lines at x = ±leg
    left = _item("left_bowl", "bowl", mo.Static((-leg, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)), container=True)
    right = _item("right_bowl", "fruit_bowl", mo.Static((leg, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)), container=True)
    top = y_pipe + float(pipe.model.mesh.bounds[1][1])
    src_model = build("cup")
    lip_local = _lip(src_model)
    lip_world = np.array([PIPE_LIP_X, top + PIPE_LIP_ABOVE, 0.0])
    motion = mo.pour("hold", lip_local, lip_world, start=0.3, speed=PIPE_POUR_SPEED)
    source = SceneItem("source", "cup", {}, src_model, src_model.sdf(), motion, True)
    volume = round(PIPE_FILL * src_model.capacity_ml * (QUICK_FILL if quick else 1.0), 1)
    leak, _ = source_sites(0, src_model, volume)

    def blockage(fraction, extra):
        side = "left" if extra.get("leg", 0.0) < 0.5 else "right"
        return 1, build("pipe_junction", **PIPE, **{side: "full" if fraction >= 0.95 else float(fraction)}).sdf()

    cam = _camera(rng, list(PIPE_EYE), [0.0, y_pipe - PIPE_LOOK_BELOW, 0.0], quick)
    duration = motion.end + (1.0 if quick else 2.5)
    return Setup("pipe", (source, pipe, left, right, _table()), (("source", volume),), (cam,), duration,
                 "pipe_feed", {"speed": PIPE_POUR_SPEED}, leak_site=leak, blockage_site=blockage)


def _plate(rng, quick: bool) -> Setup:
    bowl_model = build("bowl")
    plate_model = build("plate", rim_height=0.01)    # a shallow plate: liquid leaves it at ~30°
    r_plate = 0.5 * float(plate_model.mesh.extents[0])
    r_bowl = 0.5 * float(bowl_model.mesh.extents[0])
    rim_bowl = float(bowl_model.mesh.bounds[1][1])
    height = rim_bowl + 0.09
    target = int(rng.integers(8))
    tilt = mo.plate_tilt(target, tilt_deg=float(rng.uniform(32.0, 38.0)), start=0.3 if quick else 1.0,
                         centre=(0.0, height, 0.0))
    plate = SceneItem("plate", "plate", {"rim_height": 0.01}, plate_model, plate_model.sdf(), tilt, True)
    ring = r_plate + r_bowl - 0.02                     # bowls tucked under the plate's edge
    items = [plate]
    for k in range(8):
        phi = 2 * math.pi * k / 8
        pose = np.array([ring * math.cos(phi), 0.0, ring * math.sin(phi), 0.0, 0.0, 0.0, 1.0])
        items.append(SceneItem(f"bowl{k}", "bowl", {}, bowl_model, bowl_model.sdf(), mo.Static(tuple(pose)), True))
    volume = round(min(60.0, 0.5 * plate_model.capacity_ml) * (QUICK_FILL if quick else 1.0), 1)
    cam = _camera(rng, [0.0, 0.55, 0.55], [0.0, 0.0, 0.0], quick)
    duration = tilt.end + (1.0 if quick else 2.5)
    return Setup("plate_tilt", tuple(items) + (_table(),), (("plate", volume),), (cam,), duration, "plate_tilt",
                 {"target": float(target)})


def _ladle(rng, quick: bool) -> Setup:
    size = dict(length=0.10, width=0.08, depth=0.05) if quick else dict(length=0.14, width=0.10, depth=0.06)
    basin = _item("basin", "basin", mo.Static(), container=True, **size)
    bowl_model = build("bowl")
    ladle_model = build("ladle")
    b_lo, b_hi = basin.model.cavity.bounds
    fill = round(0.3 * basin.model.capacity_ml, 1)
    surface_y = float(basin.model.height_for_volume(fill))
    centre_local = np.asarray(ladle_model.cavity.centroid, float)
    x_bowl = float(b_hi[0]) + 0.5 * float(bowl_model.mesh.extents[0]) + 0.03
    target = SceneItem("target", "bowl", {}, bowl_model, bowl_model.sdf(),
                       mo.Static((x_bowl, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)), True)
    over = np.array([x_bowl - 0.02, float(bowl_model.mesh.bounds[1][1]) + 0.08, 0.0])
    motion = mo.ladle_scoop(centre_local, [0.5 * float(b_lo[0] + b_hi[0]), surface_y, 0.0], over)
    ladle = SceneItem("ladle", "ladle", {}, ladle_model, ladle_model.sdf(), motion, True)
    cam = _camera(rng, [x_bowl / 2, 0.3, 0.7], [x_bowl / 2, 0.06, 0.0], quick)
    return Setup("ladle", (ladle, basin, target, _table()), (("basin", fill),), (cam,), motion.end + 1.0,
                 "ladle_scoop", {})


SCENES: dict[str, Callable] = {
    "pour_partial": lambda rng, quick, **kw: _pour("partial", rng, quick, **kw),
    "pour_hold": lambda rng, quick, **kw: _pour("hold", rng, quick, **kw),
    "pour_dump": lambda rng, quick, **kw: _pour("dump", rng, quick, **kw),
    "catching": _catching,
    "pipe": _pipe,
    "plate_tilt": _plate,
    "ladle": _ladle,
}


#: What a pour scene lets a caller choose instead of the seed (evaluation benchmarks).
CHOICES = {"source": SOURCES, "target": TARGETS, "fraction": None, "source_scale": None}


def build_setup(name: str, rng: np.random.Generator, quick: bool = False, **choices) -> Setup:
    """The scene ``name`` randomised by ``rng``; ``quick``: sped-up, shortened, 320×240.

    ``choices`` (pour scenes only) fix what the seed would otherwise draw: ``source`` (one of
    ``SOURCES``), ``target`` (one of ``TARGETS``), ``fraction`` (initial fill of the source,
    0 ≤ fraction ≤ 1, 0 = an empty source), ``source_scale`` (the source's lengths but its
    wall × this, in (0, 1]: a smaller cup of the same shape). Every other draw of the seed
    stays the same.
    """
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; known: {', '.join(SCENES)}")
    choices = {k: v for k, v in choices.items() if v is not None}
    if choices:
        if not name.startswith("pour_"):
            raise ValueError(f"scene {name!r} takes no choices (only pour scenes do); got {sorted(choices)}")
        for key, value in choices.items():
            if key not in CHOICES:
                raise ValueError(f"unknown scene choice {key!r}; known: {', '.join(CHOICES)}")
            allowed = CHOICES[key]
            if allowed is not None and value not in allowed:
                raise ValueError(f"{key} {value!r} is not one of {', '.join(allowed)}")
        if "fraction" in choices and not 0.0 <= float(choices["fraction"]) <= 1.0:
            raise ValueError(f"fill fraction {choices['fraction']} must be in [0, 1] (0 = empty)")
    return dataclasses.replace(SCENES[name](rng, quick, **choices), quick=quick)
