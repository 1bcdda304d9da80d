"""Procedural object models at real sizes (thesis ch. 4.2.1, 7.4, 8.3), object frame, m, y up.

Every builder returns an :class:`~liquidtwin.geometry.meshes.ObjectModel`. Round containers
are revolved profiles: the inner surface is drawn from the axis along the floor and up the
wall to the rim, the outer surface is that line offset by the wall thickness, so walls have a
constant normal thickness and the cavity (the inner profile closed at the rim) is exact.
Handles are swept tubes stitched into holes cut in the revolved wall (no boolean union), so
each mesh is a single closed surface. Rectangular parts are unions of boxes.

The thesis gives no dimensions; these are typical household sizes (capacities in the
docstrings, checked by the tests). Containers stand on y = 0 with the opening up; sources
pour over their rim on the −x side (``lip``), handles point to +x.
"""

from __future__ import annotations

import math

import numpy as np

from ._build import Builder, boxes_mesh, hole_loop, offset_profile, subdivide, sweep_loops
from .object_model import MIN_WALL, ObjectModel

SECTIONS = 72


def _check(name: str, **values) -> None:
    for key, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name}: {key} must be a positive length in m, got {value!r}")
    wall = values.get("wall")
    if wall is not None and wall < MIN_WALL:
        raise ValueError(f"{name}: wall {wall * 1e3:.2f} mm is thinner than "
                         f"{MIN_WALL * 1e3:.0f} mm; the simulator's anti-clipping and SDF grid "
                         f"need walls of at least that")


def _arc(r0, y0, r1, y1, n=12):
    """Quarter-ellipse from (r0, y0) (horizontal tangent) to (r1, y1) (vertical tangent), (n, 2)."""
    t = np.linspace(0.0, np.pi / 2, n + 1)[1:]
    return np.stack([r0 + (r1 - r0) * np.sin(t), y0 + (y1 - y0) * (1 - np.cos(t))], 1)


def _revolved(name, inner, wall, *, rim=None, sections=SECTIONS, lip=False, handle=None,
              anchors=None):
    """ObjectModel from an inner (r, y) polyline (P, 2) starting on the axis at the floor.

    ``rim``: index of the inner point where the cavity ends (default: the last; a flange
    may follow it). ``handle``: a :class:`_Handle` cut into and swept out of the outer wall.
    ``lip``: give the model a pouring lip (the outer rim edge at −x).
    """
    inner = np.asarray(inner, float)
    outer = offset_profile(inner, wall)
    profile = np.concatenate([outer, inner[::-1]])
    b = Builder()
    holes = handle.holes(outer) if handle is not None else []
    rings = b.revolve(profile, sections, holes)
    if handle is not None:
        handle.attach(b, rings, holes)
    mesh = b.mesh(name)
    rim = len(inner) - 1 if rim is None else rim
    cb = Builder()
    cb.revolve(np.concatenate([inner[:rim + 1], [[0.0, inner[rim, 1]]]]), sections)
    lip_point = np.array([-outer[rim:, 0].max(), float(profile[:, 1].max()), 0.0])
    return ObjectModel(name, mesh, float(wall), cb.mesh(name + " cavity"),
                       lip_point if lip else None, anchors or {})


class _Handle:
    """A handle on the outer wall at +x: a swept rectangular tube out of hole(s) in the wall.

    Args:
      radius: outer wall radius, m. rows: profile rows the hole spans (the tube's thickness).
      width: tangential size, m (rounded to whole wall sections). sections: of the revolve.
      path: (P, 2) (x, y) tube centre line between the holes (ends excluded), m.
      y_holes: heights of the hole centres on the outer wall, m: two for a loop handle
        (mug), one for a stick that ends in a cap (pan, ladle).
    """

    def __init__(self, radius, rows, width, sections, path, y_holes):
        self.k = max(1, round(width / (2 * math.pi * radius / sections)))
        self.path, self.y_holes, self.rows = path, y_holes, rows

    def holes(self, outer):
        out = []
        for y in self.y_holes:
            r_off = np.abs(outer[:, 0] - outer[:, 0].max())
            i = int(np.argmin(np.abs(outer[:, 1] - y) + 10 * r_off)) - 1   # ring of the centre
            out.append(((i - self.rows // 2, i + self.rows - self.rows // 2), (0, self.k)))
        return out

    def attach(self, b, rings, holes):
        loop_a, pos = hole_loop(rings, *holes[0])
        xyz = b.coords(loop_a)
        centre = xyz.mean(0)
        uv = np.stack([xyz[:, 2], xyz[:, 1] - centre[1]], 1)
        loops = [loop_a] + sweep_loops(b, uv, self.path)
        if len(holes) == 2:
            (a0, a1), _ = holes[0]
            (b0, _), _ = holes[1]
            loops.append(rings[b0 + a1 - pos[:, 0], pos[:, 1]])
        b.tube(loops, cap_end=len(holes) == 1)


def cup(radius: float = 0.0375, bottom_radius: float = 0.03, height: float = 0.11,
        wall: float = 0.003) -> ObjectModel:
    """Tapered plastic cup (source): inner radius 3.75 cm at the rim, 3 cm at the floor, 11 cm
    tall, 3 mm walls; holds ≈ 380 ml to the rim."""
    _check("cup", radius=radius, bottom_radius=bottom_radius, height=height, wall=wall)
    inner = [[0.0, wall], [bottom_radius, wall], [radius, height]]
    return _revolved("cup", subdivide(inner, 0.01), wall, lip=True)


def bottle(radius: float = 0.035, height: float = 0.25, body_height: float = 0.17,
           neck_radius: float = 0.0125, wall: float = 0.003) -> ObjectModel:
    """Glass bottle (source): 7 cm wide body up to 17 cm, rounded shoulder, 2.5 cm neck to
    25 cm; holds ≈ 640 ml to the rim."""
    _check("bottle", radius=radius, height=height, body_height=body_height,
           neck_radius=neck_radius, wall=wall)
    shoulder = 0.5 * (height - body_height)
    if not (neck_radius - wall >= 0.004 and neck_radius < radius and shoulder > wall):
        raise ValueError("bottle: need neck_radius - wall >= 4 mm, neck_radius < radius and "
                         "body_height well below height")
    ri, rn = radius - wall, neck_radius - wall
    t = np.linspace(0, np.pi / 2, 10)[1:]
    sh = np.stack([rn + (ri - rn) * np.cos(t), body_height + shoulder * np.sin(t)], 1)
    body = subdivide([[ri, wall], [ri, body_height]], 0.02)
    neck = subdivide([sh[-1], [rn, height]], 0.02)
    inner = np.concatenate([[[0.0, wall]], body, sh, neck[1:]])
    return _revolved("bottle", inner, wall, lip=True)


def mug(radius: float = 0.036, height: float = 0.095, wall: float = 0.004,
        handle: float = 1.0) -> ObjectModel:
    """Ceramic mug (source): inner radius 3.6 cm, 9.5 cm tall, 4 mm walls, a D-shaped handle
    on +x (``handle=0`` leaves it off); holds ≈ 350 ml to the rim."""
    _check("mug", radius=radius, height=height, wall=wall)
    rows = 2
    dy = 0.004
    n = max(4, round((height - wall) / dy))
    wall_pts = np.stack([np.full(n, radius), wall + (height - wall) * np.arange(1, n + 1) / n], 1)
    inner = np.concatenate([[[0.0, wall], [radius, wall]], wall_pts])
    ro = radius + wall
    h = None
    if handle:
        step = (height - wall) / n
        ya = wall + step * round((0.8 * height - wall) / step)
        yb = wall + step * round((0.3 * height - wall) / step)
        rho, reach = 0.5 * (ya - yb), 0.012
        phi = np.linspace(np.pi / 2, -np.pi / 2, 15)
        arc = np.stack([ro + reach + rho * np.cos(phi), 0.5 * (ya + yb) + rho * np.sin(phi)], 1)
        path = np.concatenate([[[ro + reach / 3, ya], [ro + 2 * reach / 3, ya]], arc,
                               [[ro + 2 * reach / 3, yb], [ro + reach / 3, yb]]])
        h = _Handle(ro, rows, 0.012, SECTIONS, path, [ya, yb])
    anchors = {"handle": [ro + 0.03, 0.55 * height, 0.0]} if handle else {}
    return _revolved("mug", inner, wall, lip=True, handle=h, anchors=anchors)


def _bowl(name, radius, depth, base_radius, wall, flange=0.0, sections=SECTIONS):
    _check(name, radius=radius, depth=depth, wall=wall)
    if not 0 <= base_radius < radius:
        raise ValueError(f"{name}: base_radius must be in [0, radius), got {base_radius}")
    inner = [[0.0, wall]] + ([[base_radius, wall]] if base_radius > 0 else [])
    inner = np.concatenate([inner, _arc(base_radius, wall, radius, wall + depth, 14)])
    rim = len(inner) - 1
    if flange > 0:
        inner = np.concatenate([inner, [[radius + flange, wall + depth]]])
    return _revolved(name, inner, wall, rim=rim, sections=sections)


def bowl(radius: float = 0.077, depth: float = 0.06, base_radius: float = 0.035,
         wall: float = 0.003) -> ObjectModel:
    """Mixing bowl (target): 16 cm wide, 6 cm deep, 3 mm walls; holds ≈ 890 ml."""
    return _bowl("bowl", radius, depth, base_radius, wall)


def fruit_bowl(radius: float = 0.12, depth: float = 0.085, base_radius: float = 0.06,
               wall: float = 0.004) -> ObjectModel:
    """Fruit bowl (target): 25 cm wide, 8.5 cm deep, 4 mm walls; holds ≈ 3.1 l."""
    return _bowl("fruit_bowl", radius, depth, base_radius, wall)


def dog_dish(radius: float = 0.09, depth: float = 0.05, base_radius: float = 0.07,
             flange: float = 0.02, wall: float = 0.003) -> ObjectModel:
    """Plastic dog dish (target): sloped wall from 14 to 18 cm wide, 5 cm deep, a 2 cm flat
    flange round the rim, 3 mm walls; holds ≈ 1 l."""
    _check("dog_dish", radius=radius, depth=depth, base_radius=base_radius, flange=flange,
           wall=wall)
    if base_radius >= radius:
        raise ValueError("dog_dish: base_radius must be smaller than radius")
    bowl_part = subdivide([[0.0, wall], [base_radius, wall], [radius, wall + depth]], 0.02)
    inner = np.concatenate([bowl_part, [[radius + flange, wall + depth]]])
    return _revolved("dog_dish", inner, wall, rim=len(bowl_part) - 1)


def pan(radius: float = 0.11, depth: float = 0.045, wall: float = 0.004,
        handle_length: float = 0.14) -> ObjectModel:
    """Cast pan (target): 22 cm inside, 4.5 cm deep, 4 mm walls, a 14 cm handle on +x
    rising 10°; holds ≈ 1.7 l."""
    _check("pan", radius=radius, depth=depth, wall=wall, handle_length=handle_length)
    rows, n = 2, max(4, round(depth / 0.005))
    wall_pts = np.stack([np.full(n, radius), wall + depth * np.arange(1, n + 1) / n], 1)
    inner = np.concatenate([[[0.0, wall], [radius, wall]], wall_pts])
    ro, step = radius + wall, depth / n
    yh = wall + step * round((0.6 * depth) / step)
    a = math.radians(10)
    s = np.linspace(0, 1, 8)[1:]
    path = np.concatenate([[[ro + 0.008, yh], [ro + 0.016, yh]],
                           np.stack([ro + 0.016 + s * handle_length * math.cos(a),
                                     yh + s * handle_length * math.sin(a)], 1)])
    h = _Handle(ro, rows, 0.02, 96, path, [yh])
    return _revolved("pan", inner, wall, sections=96, handle=h,
                     anchors={"handle": path[-1].tolist() + [0.0]})


def plate(radius: float = 0.13, base_radius: float = 0.08, rim_height: float = 0.015,
          flange: float = 0.025, wall: float = 0.004) -> ObjectModel:
    """Dinner plate: 26 cm across, flat centre 16 cm, rises 1.5 cm to a 2.5 cm flat rim,
    4 mm thick; holds ≈ 400 ml before spilling over the rim."""
    _check("plate", radius=radius, base_radius=base_radius, rim_height=rim_height, flange=flange,
           wall=wall)
    if base_radius >= radius - flange:
        raise ValueError("plate: base_radius must be smaller than radius - flange")
    inner = [[0.0, wall], [base_radius, wall], [radius - flange, wall + rim_height],
             [radius, wall + rim_height]]
    inner = subdivide(inner, 0.03)
    rim = int(np.argmin(np.abs(inner[:, 0] - (radius - flange))))
    return _revolved("plate", inner, wall, rim=rim, sections=96)


def ladle(radius: float = 0.036, depth: float = 0.032, band: float = 0.012, wall: float = 0.003,
          handle_length: float = 0.2, handle_angle_deg: float = 65.0) -> ObjectModel:
    """Soup ladle (source and scoop): half-ellipsoid bowl 7.2 cm wide inside, 3.2 cm deep, a
    1.2 cm vertical band to the rim, 3 mm walls, a flat handle leaving at +x and rising
    at 65°; holds ≈ 135 ml."""
    _check("ladle", radius=radius, depth=depth, band=band, wall=wall, handle_length=handle_length)
    rows, n = 2, 4
    band_pts = np.stack([np.full(n, radius), wall + depth + band * np.arange(1, n + 1) / n], 1)
    inner = np.concatenate([[[0.0, wall]], _arc(0.0, wall, radius, wall + depth, 16), band_pts])
    ro = radius + wall
    yh = wall + depth + band / 2
    a = math.radians(handle_angle_deg)
    bend, turn = 0.02, np.linspace(0, a, 8)[1:]
    x0 = ro + 0.008
    curve = np.stack([x0 + bend * np.sin(turn), yh + bend * (1 - np.cos(turn))], 1)
    s = np.linspace(0, 1, 8)[1:]
    straight = curve[-1] + np.outer(s * (handle_length - 0.03), [math.cos(a), math.sin(a)])
    path = np.concatenate([[[ro + 0.004, yh], [x0, yh]], curve, straight])
    h = _Handle(ro, rows, 0.016, SECTIONS, path, [yh])
    return _revolved("ladle", inner, wall, lip=True, handle=h,
                     anchors={"handle": np.append(path[-1], 0.0)})


def basin(length: float = 0.30, width: float = 0.20, depth: float = 0.12,
          wall: float = 0.005) -> ObjectModel:
    """Rectangular plastic basin (the ladle scene's container): 30 × 20 cm inside along x × z,
    12 cm deep, 5 mm walls; holds 7.2 l."""
    _check("basin", length=length, width=width, depth=depth, wall=wall)
    hx, hz = length / 2, width / 2
    lo, hi = np.array([-hx, wall, -hz]), np.array([hx, depth + wall, hz])
    outer = (lo - [wall, wall, wall], hi + [wall, 0.0, wall], True)
    hole = (lo, hi + [0.0, wall, 0.0], False)
    cavity = boxes_mesh([(lo, hi, True)], "basin cavity")
    return ObjectModel("basin", boxes_mesh([outer, hole], "basin"), wall, cavity, None, {})
