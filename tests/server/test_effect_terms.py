"""The physical terms hidden effects are made of, checked against closed-form motion, and
the SDF edits that make leaks and blockages."""

import math

import numpy as np
import pytest
import torch

from liquidtwin.scenes import shapes
from liquidtwin.sim import (FluidModel, QuadraticDrag, WallAdhesion, carve, cylinder_sdf, lattice, make_state,
                            rollout, solidify)


def _single(model, x, v):
    return make_state(torch.tensor([x], dtype=torch.float64), torch.tensor([v], dtype=torch.float64),
                      dtype=torch.float64, poses=torch.zeros(len(model.objects), 7, dtype=torch.float64)
                      + torch.tensor([0, 0, 0, 0, 0, 0, 1.0], dtype=torch.float64))


def test_quadratic_drag_gives_the_analytic_fall_speed():
    c = 2.0                                   # 1/m → terminal speed sqrt(g/c) = 2.21 m/s
    model = FluidModel.create(0.01, dt=1e-3, terms=(QuadraticDrag(torch.tensor(c)),))
    state, states = rollout(model, _single(model, [0, 0, 0], [0, 0, 0]), steps=1500)
    vt = math.sqrt(9.8 / c)
    for k in (200, 700, 1499):
        t = (k + 1) * 1e-3
        want = -vt * math.tanh(9.8 * t / vt)
        assert float(states[k].v[0, 1]) == pytest.approx(want, rel=5e-3)


def test_wall_adhesion_slows_particles_near_walls_only():
    floor = shapes.floor_grid(half_xz=0.2, depth=0.02, cell=0.002)
    k, delta = 20.0, 0.006
    model = FluidModel.create(0.01, dt=1e-3, gravity=(0, 0, 0), objects=[floor],
                              terms=(WallAdhesion(torch.tensor(k), delta),))
    y_near, y_far = 0.002, 0.02
    near = rollout(model, _single(model, [0, y_near, 0], [0.1, 0, 0]), steps=100)[0]
    far = rollout(model, _single(model, [0, y_far, 0], [0.1, 0, 0]), steps=100)[0]
    w = 1 - y_near / delta
    # Semi-implicit Euler of dv/dt = −k w v: v_n = v0 (1 − dt k w)^n.
    assert float(near.v[0, 0]) == pytest.approx(0.1 * (1 - 1e-3 * k * w) ** 100, rel=0.02)
    assert float(far.v[0, 0]) == pytest.approx(0.1, rel=1e-9)


def test_carve_makes_a_hole_and_solidify_a_plug():
    cup = shapes.cup_grid(0.03, 0.08, 0.003, cell=0.001)
    hole = cylinder_sdf([0.0315, 0.01, 0.0], [1, 0, 0], 0.004, 0.004)
    leaky = carve(cup, hole)
    at = torch.tensor([[0.0315, 0.01, 0.0]], dtype=torch.float32)
    assert float(cup.sample_local(at)) < 0 < float(leaky.sample_local(at))
    far = torch.tensor([[-0.0315, 0.03, 0.0]], dtype=torch.float32)
    assert float(leaky.sample_local(far)) == pytest.approx(float(cup.sample_local(far)))
    plug = solidify(cup, cylinder_sdf([0, 0.06, 0], [0, 1, 0], 0.02, 0.005))
    assert float(plug.sample_local(torch.tensor([[0.0, 0.06, 0.0]]))) < 0
    with pytest.raises(ValueError, match="does not touch"):
        carve(cup, cylinder_sdf([1.0, 1.0, 1.0], [1, 0, 0], 0.001, 0.001))
    with pytest.raises(ValueError, match="edge"):
        solidify(cup, cylinder_sdf([0, 0.06, 0], [1, 0, 0], 0.02, 0.5))


def test_liquid_runs_out_of_a_leaky_cup_and_stays_in_an_intact_one():
    h = 0.011
    cup = shapes.cup_grid(0.03, 0.06, 0.003, cell=0.001)
    floor = shapes.floor_grid(half_xz=0.3, depth=0.02, cell=0.004)
    leaky = carve(cup, cylinder_sdf([0.0315, 0.012, 0.0], [1, 0, 0], 0.006, 0.006))
    spacing = 0.55 * h
    pts = lattice([-0.024, 0.006, -0.024], [0.024, 0.03, 0.024], spacing)
    pts = pts[np.linalg.norm(pts[:, [0, 2]], axis=1) < 0.026]
    lifted = torch.tensor([0, 0.02, 0, 0, 0, 0, 1.0], dtype=torch.float64)
    ident = torch.tensor([0, 0, 0, 0, 0, 0, 1.0], dtype=torch.float64)
    out = {}
    for name, grid in (("intact", cup), ("leaky", leaky)):
        model = FluidModel.create(h, dt=1 / 120, iterations=4, relaxation=4.0, objects=[grid, floor])
        state = make_state(torch.tensor(pts) + torch.tensor([0, 0.02, 0]), poses=torch.stack([lifted, ident]))
        final, _ = rollout(model, state, steps=60)
        local = final.x.double() - lifted[:3]
        inside = (local[:, 1] > 0) & (local[:, 0:3:2].norm(dim=1) < 0.03)
        out[name] = int(inside.sum())
    assert out["intact"] == len(pts)
    assert out["leaky"] < 0.97 * len(pts)
