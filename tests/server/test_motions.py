"""Scripted trajectories: the pivot stays put, angles follow the thesis's pours, tilts go the
right way, and everything is a proper rigid motion (checked against independent maths)."""

import math

import numpy as np
import pytest
import torch

from liquidtwin.scenes import motions as mo
from liquidtwin.sim import quat_to_matrix


def test_quaternion_helpers_agree_with_torch_and_compose():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(5, 4))
    assert np.allclose(mo.quat_matrix(q), quat_to_matrix(torch.from_numpy(q)).numpy(), atol=1e-12)
    a = np.concatenate([rng.normal(size=3), mo.quat_axis_angle(rng.normal(size=3), 0.7)])
    b = np.concatenate([rng.normal(size=3), mo.quat_axis_angle(rng.normal(size=3), -1.3)])
    p = rng.normal(size=(4, 3))
    assert np.allclose(mo.transform(mo.compose(a, b), p), mo.transform(a, mo.transform(b, p)), atol=1e-12)


@pytest.mark.parametrize("kind", sorted(mo.POUR_KINDS))
def test_pour_keeps_the_lip_fixed_and_reaches_the_thesis_angle(kind):
    lip_local, lip_world = np.array([-0.04, 0.1, 0.0]), np.array([0.1, 0.25, 0.0])
    m = mo.pour(kind, lip_local, lip_world, start=0.5)
    angle, t_tilt, t_hold, _ = mo.POUR_KINDS[kind]
    for t in np.linspace(0, m.end + 1, 40):
        assert np.allclose(mo.transform(m(t), lip_local), lip_world, atol=1e-12)
    up = lambda t: mo.quat_matrix(m(t)[3:]) @ np.array([0.0, 1.0, 0.0])
    tilt = lambda t: math.degrees(math.acos(np.clip(up(t)[1], -1, 1)))
    assert tilt(0.4) == pytest.approx(0.0, abs=1e-9)
    assert tilt(0.5 + t_tilt) == pytest.approx(angle, abs=1e-6)
    assert up(0.5 + t_tilt)[0] < 0          # the opening tips towards −x
    if t_hold is None:
        assert tilt(m.end + 5) == pytest.approx(angle, abs=1e-6)
    else:
        assert tilt(0.5 + t_tilt + 0.5 * t_hold) == pytest.approx(angle, abs=1e-6)
        assert tilt(m.end + 1) == pytest.approx(0.0, abs=1e-6)


def test_pour_is_smooth_no_jumps():
    m = mo.pour("dump", [0, 0.1, 0], [0, 0.3, 0])
    ts = np.linspace(0, m.end + 0.5, 2000)
    poses = mo.sample([m], ts)[:, 0]
    assert np.abs(np.diff(poses, axis=0)).max() < 0.01


@pytest.mark.parametrize("target", range(8))
def test_plate_tilt_lowers_the_side_facing_the_target(target):
    m = mo.plate_tilt(target, tilt_deg=10.0)
    phi = 2 * math.pi * target / 8
    rim = 0.1 * np.array([math.cos(phi), 0.0, math.sin(phi)])
    y_end = mo.transform(m(m.end), rim)[1]
    assert y_end == pytest.approx(-0.1 * math.sin(math.radians(10.0)), abs=1e-9)
    opposite = mo.transform(m(m.end), -rim)[1]
    assert opposite > 0


def test_slide_translates_without_rotation():
    m = mo.slide([0, 0, 0], [0.2, 0, 0], start=1.0, duration=2.0)
    assert np.allclose(m(0.5), mo.IDENTITY)
    assert np.allclose(m(2.0)[:3], [0.1, 0, 0]) and np.allclose(m(2.0)[3:], [0, 0, 0, 1])
    assert np.allclose(m(9.0)[:3], [0.2, 0, 0])


def test_ladle_dips_below_the_surface_then_tips_over_the_target():
    surface, over = np.array([0.0, 0.08, 0.0]), np.array([0.3, 0.25, 0.0])
    m = mo.ladle_scoop([0.0, 0.0, 0.0], surface, over)
    ts = np.linspace(0, m.end, 400)
    ys = np.array([m(t)[1] for t in ts])
    assert ys.min() < surface[1] - 0.03
    assert np.allclose(m(m.end)[:3] - mo.quat_matrix(m(m.end)[3:]) @ np.zeros(3), over)
    assert mo.quat_matrix(m(m.end)[3:])[1, 1] < 0     # bowl of the ladle upside down-ish


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="unknown pour"):
        mo.pour("splash", [0, 0, 0], [0, 0, 0])
    with pytest.raises(ValueError, match="target"):
        mo.plate_tilt(8)
    with pytest.raises(ValueError, match="decrease"):
        mo.Profile.of((1.0, 0.0), (0.5, 1.0))
