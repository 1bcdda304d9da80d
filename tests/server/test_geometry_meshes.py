"""Procedural object meshes and the volume-below-a-plane code, against closed forms.

References are analytic (cylinder, cones, spherical cap, frustum, box volumes), an identity
(volume below + volume above = total), and Möller–Trumbore rays that are independent of
the parity test used for point-in-mesh queries.
"""

import math

import numpy as np
import pytest
import trimesh

from liquidtwin import geometry as g
from liquidtwin.geometry import _rays

Y_UP = trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0])   # +z → +y


def _standing(mesh, dy):
    """Rotate a z-axis trimesh primitive to the y axis and lift it by dy."""
    m = mesh.copy()
    m.apply_transform(Y_UP)
    m.apply_translation([0.0, dy, 0.0])
    return m


R, H = 0.05, 0.12
CYLINDER = _standing(trimesh.creation.cylinder(radius=R, height=H, sections=256), H / 2)
CONE_UP = _standing(trimesh.creation.cone(radius=R, height=H, sections=256), 0.0)  # apex at H
CONE_DOWN = CONE_UP.copy()
CONE_DOWN.apply_transform(trimesh.transformations.reflection_matrix([0, H / 2, 0], [0, 1, 0]))
SPHERE = trimesh.creation.icosphere(subdivisions=5, radius=R)
SPHERE.apply_translation([0.0, R, 0.0])

CLOSED_FORMS = {
    "cylinder": (CYLINDER, H, lambda h: math.pi * R**2 * h),
    "cone_apex_up": (CONE_UP, H, lambda h: math.pi * R**2 * H / 3 * (1 - (1 - h / H) ** 3)),
    "cone_apex_down": (CONE_DOWN, H, lambda h: math.pi * R**2 / (3 * H**2) * h**3),
    "spherical_cap": (SPHERE, 2 * R, lambda h: math.pi * h * h * (3 * R - h) / 3),
}


@pytest.mark.parametrize("name", sorted(CLOSED_FORMS))
def test_volume_below_matches_closed_forms_and_inverts(name):
    mesh, top, exact = CLOSED_FORMS[name]
    for frac in (0.05, 0.3, 0.5, 0.77, 0.95):
        h = frac * top
        got = g.volume_below(mesh, h)
        assert got == pytest.approx(exact(h), rel=0.01), (name, frac)
        # the inverse lands on the same plane
        assert g.height_for_volume(mesh, got) == pytest.approx(h, abs=1e-6)
    assert g.volume_below(mesh, -1.0) == 0.0
    assert g.volume_below(mesh, top + 1.0) == pytest.approx(mesh.volume, rel=1e-9)


def test_volume_below_plus_volume_above_is_the_total():
    """Mirror the mug upside down: what lies above y = h is what the mirror holds below -h."""
    mug = g.build("mug").mesh
    mirror = mug.copy()
    mirror.apply_transform(trimesh.transformations.reflection_matrix([0, 0, 0], [0, 1, 0]))
    assert mirror.volume > 0                              # trimesh re-winds reflected faces
    for h in (0.011, 0.03, 0.0601, 0.094):
        total = g.volume_below(mug, h) + g.volume_below(mirror, -h)
        assert total == pytest.approx(mug.volume, rel=1e-9)


def test_height_for_volume_refuses_more_than_the_capacity():
    with pytest.raises(ValueError, match=r"at most 942\.\d ml"):
        g.height_for_volume(CYLINDER, 1e-3)            # 1 l into 0.94 l
    with pytest.raises(ValueError):
        g.height_for_volume(CYLINDER, -1e-6)


def test_contains_matches_an_analytic_sphere():
    pts = np.random.default_rng(0).uniform(-0.06, 0.16, (4000, 3))
    got = g.contains(SPHERE, pts)
    d = np.linalg.norm(pts - [0, R, 0], axis=1)
    clear = np.abs(d - R) > 2e-4                       # the icosphere's facets are within 0.1 mm
    assert np.array_equal(got[clear], d[clear] < R)


# ---------------------------------------------------------------- procedural models

CAPACITY_ML = {        # typical household sizes: (low, high) ml to the rim
    "cup": (330, 430), "bottle": (550, 800), "mug": (300, 420), "bowl": (700, 1000),
    "fruit_bowl": (2500, 3500), "dog_dish": (800, 1200), "pan": (1400, 2400), "plate": (250, 500),
    "ladle": (100, 160), "basin": (7000, 7400),
}
VARIANTS = [(n, {}) for n in sorted(g.MODELS)] + [
    ("pipe_junction", {"left": "partial"}), ("pipe_junction", {"right": "full"}),
    ("mug", {"handle": 0})]
IDS = [n + "".join(f"-{k}={v}" for k, v in p.items()) for n, p in VARIANTS]


def _enclosed(points, mesh):
    """Rays from each point along ±x, ±z and −y all hit the solid (Möller–Trumbore)."""
    hit = np.ones(len(points), bool)
    for d in ([1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1], [0, -1, 0]):
        dirs = np.tile(np.asarray(d, float), (len(points), 1))
        hit &= np.isfinite(_rays.first_hit(points, dirs, mesh.vertices, mesh.faces))
    return hit


@pytest.mark.parametrize("name,params", VARIANTS, ids=IDS)
def test_model_is_a_closed_solid_with_a_plausible_cavity(name, params):
    m = g.build(name, **params)
    assert m.mesh.is_watertight and m.mesh.is_winding_consistent
    assert m.mesh.volume > 0
    assert m.mesh.bounds[0, 1] == pytest.approx(0.0, abs=1e-12)        # stands on y = 0
    assert g.estimate_wall(m.mesh) >= 0.95 * m.wall >= 0.95 * g.MIN_WALL
    if name == "pipe_junction":
        assert m.cavity is None and set(m.anchors) == {"inlet", "left_outlet", "right_outlet"}
        return
    lo, hi = CAPACITY_ML[name]
    assert lo < m.capacity_ml < hi
    assert m.cavity.is_watertight and m.cavity.volume > 0
    # points inside the cavity: never inside the solid, and walled in on all sides and below
    rng = np.random.default_rng(1)
    box = m.cavity.bounds
    pts = rng.uniform(box[0], box[1], (3000, 3))
    pts = pts[m.in_cavity(pts)][:150]
    assert len(pts) > 50
    assert not g.contains(m.mesh, pts).any()
    assert _enclosed(pts, m.mesh).all()
    # the rim plane is the cavity's top and within the solid's height
    assert m.rim_height <= m.mesh.bounds[1, 1] + 1e-12
    assert m.volume_below_ml(m.rim_height) == pytest.approx(m.capacity_ml)


def test_cavity_volumes_match_closed_forms():
    n = g.models.SECTIONS
    polygon = n / (2 * math.pi) * math.sin(2 * math.pi / n)       # inscribed 72-gon area factor
    cup = g.build("cup")
    depth = 0.11 - 0.003
    frustum = math.pi * depth / 3 * (0.0375**2 + 0.0375 * 0.03 + 0.03**2)
    assert cup.capacity_ml == pytest.approx(polygon * frustum * 1e6, rel=1e-6)
    mug = g.build("mug")
    cylinder = math.pi * 0.036**2 * (0.095 - 0.004)
    assert mug.capacity_ml == pytest.approx(polygon * cylinder * 1e6, rel=1e-6)
    assert g.build("basin").capacity_ml == pytest.approx(300 * 200 * 120 / 1000, rel=1e-9)
    # bowl: quarter-ellipse wall r = b + (R-b) sin t, y = w + d (1 - cos t): V = π ∫ r² dy
    b, r, d = 0.035, 0.077, 0.06
    t = np.linspace(0, math.pi / 2, 20001)
    integrand = (b + (r - b) * np.sin(t)) ** 2 * d * np.sin(t)
    exact = math.pi * np.sum(0.5 * (integrand[1:] + integrand[:-1]) * np.diff(t))
    assert g.build("bowl").capacity_ml == pytest.approx(polygon * exact * 1e6, rel=0.005)
    # filling halfway up a straight-walled mug: the height is half the liquid depth
    h = mug.height_for_volume(mug.capacity_ml / 2)
    assert h == pytest.approx(0.004 + 0.5 * (0.095 - 0.004), abs=1e-6)


def test_handles_are_stitched_into_one_closed_surface():
    with_handle, without = g.build("mug"), g.build("mug", handle=0)
    assert with_handle.mesh.volume > without.mesh.volume + 5e-6          # the handle adds material
    assert with_handle.capacity_ml == pytest.approx(without.capacity_ml)
    # one connected surface: every face reachable from face 0 across shared edges
    for m in (with_handle, g.build("pan"), g.build("ladle")):
        parts = trimesh.graph.connected_components(m.mesh.face_adjacency,
                                                   nodes=np.arange(len(m.mesh.faces)))
        assert len(parts) == 1


def test_pipe_blockages_change_the_leg_and_nothing_else():
    none = g.build("pipe_junction")
    full_l, part_l = g.build("pipe_junction", left="full"), g.build("pipe_junction", left="partial")
    part_r = g.build("pipe_junction", right="partial")
    plug = 0.012 * 0.03 * 0.03
    assert full_l.mesh.volume - none.mesh.volume == pytest.approx(plug, rel=1e-6)
    assert part_l.mesh.volume - none.mesh.volume == pytest.approx(0.6 * plug, rel=1e-6)
    assert part_r.mesh.volume == pytest.approx(part_l.mesh.volume, rel=1e-9)
    third = g.build("pipe_junction", left=0.3)
    assert third.mesh.volume - none.mesh.volume == pytest.approx(0.3 * plug, rel=1e-6)
    # rays along the left leg from the junction: low and high in the duct
    yc = 0.05 + 0.015
    for m, low, high in ((none, 0.12, 0.12), (part_l, 0.054, 0.12), (full_l, 0.054, 0.054)):
        for y, expect in ((yc - 0.01, low), (yc + 0.01, high)):
            t = _rays.first_hit(np.array([[0.0, y, 0.0]]), np.array([[-1.0, 0.0, 0.0]]),
                                m.mesh.vertices, m.mesh.faces)
            assert t[0] == pytest.approx(expect, abs=1e-9)
    for bad in ({"left": "half"}, {"right": 1.5}, {"plug_offset": 0.2}):
        with pytest.raises(ValueError):
            g.build("pipe_junction", **bad)


def test_registry_names_parameters_and_bad_values():
    assert set(g.MODELS) >= {"cup", "bottle", "mug", "bowl", "fruit_bowl", "dog_dish", "pan",
                             "plate", "ladle", "basin", "pipe_junction"}
    assert g.model_params("cup")["wall"] == 0.003
    with pytest.raises(ValueError, match="unknown object model 'teapot'.*cup"):
        g.build("teapot")
    with pytest.raises(ValueError, match=r"no parameter\(s\) \['colour'\]"):
        g.build("cup", colour=1.0)
    with pytest.raises(ValueError, match="thinner than 2 mm"):
        g.build("bowl", wall=0.001)
    with pytest.raises(ValueError, match="positive length"):
        g.build("basin", depth=float("nan"))
    assert g.build("cup", radius=0.05).capacity_ml > g.build("cup").capacity_ml


def test_sources_have_a_lip_on_the_rim_at_minus_x():
    for name in ("cup", "bottle", "mug", "ladle"):
        m = g.build(name)
        assert m.lip is not None and m.lip[0] < 0 and m.lip[2] == 0.0
        assert m.lip[1] == pytest.approx(m.mesh.bounds[1, 1] if name != "ladle" else m.rim_height)
        v = m.mesh.vertices
        rim = v[v[:, 1] > m.rim_height - 1e-3]                      # outer rim edge at −x
        assert m.lip[0] == pytest.approx(rim[:, 0].min(), abs=1e-3)
    assert g.build("bowl").lip is None


def test_layouts():
    scene = g.plate_with_bowls()
    assert len(scene) == 9 and scene[0][0].name == "plate"
    names = [o.name for o, _ in scene]
    assert len(set(names)) == 9
    centres = np.array([p[:3] for _, p in scene[1:]])
    assert np.allclose(centres[:, 1], 0.0)
    gap = np.linalg.norm(centres[:, None] - centres[None], axis=-1) + np.eye(8)
    outer = scene[1][0].mesh.bounds[1, 0]
    assert gap.min() > 2 * outer                                            # bowls do not overlap
    plate, pose = scene[0]
    assert pose[1] > scene[1][0].mesh.bounds[1, 1]                  # plate above the bowls' rims
    assert np.linalg.norm(centres[:, [0, 2]], axis=1).min() - outer > plate.mesh.bounds[1, 0] - 0.05
    (src, p_src), (dst, p_dst) = g.catching_cups()
    assert p_src[1] > dst.mesh.bounds[1, 1] and p_dst[0] < 0 and src.name != dst.name
    for _, p in scene + g.catching_cups():
        assert p.shape == (7,) and p[6] == 1.0
    with pytest.raises(ValueError):
        g.plate_with_bowls(n_bowls=8, ring_radius=0.1)
