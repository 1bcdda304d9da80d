"""FluidModel.wall_pairs = False: neighbour pairs that a wall separates are cut.

Checked against independent references: an analytic slab (a pair is separated exactly when
its particles lie on opposite faces), marching every pair's segment (the cheap rule that picks
the pairs to march must miss none on a cup, inside and out, tilted), free fall (a drop under
a plate falls as g t² / 2 once nothing holds it through the plate) and finite differences
(the step keeps its gradient)."""

import math

import numpy as np
import pytest
import torch

import liquidtwin as lt
from liquidtwin.scenes import shapes
from liquidtwin.sim import FluidModel, fused, walls
from liquidtwin.sim.neighbors import find_neighbors
from liquidtwin.sim.sdf import min_sdf

H, DT = 0.011, 1 / 120
SP = 0.55 * H
IDENTITY = torch.tensor([[0, 0, 0, 0, 0, 0, 1.0]])
BACKENDS = [False] + ([True] if fused.available() else [])


def _plate(half_thickness=0.0015):
    return shapes.sample_grid(lambda p: shapes.box(p, (0.05, half_thickness, 0.05)), (-0.056, -0.006, -0.056),
                              (0.056, 0.006, 0.056), 0.00075, 2 * half_thickness, "plate")


def _pairs(row_ptr, col) -> set:
    rows = walls.pair_rows(row_ptr)
    return set(zip(rows.tolist(), col.tolist()))


@pytest.mark.parametrize("native", BACKENDS)
def test_the_cut_on_a_slab_is_exactly_the_pairs_on_opposite_faces(native):
    rng = np.random.default_rng(3)
    x = rng.uniform([-0.03, -0.012, -0.03], [0.03, 0.012, 0.03], (3000, 3))
    x = x[np.abs(x[:, 1]) > 0.0015 + 0.0002]                  # outside the plate's material
    x = torch.as_tensor(x, dtype=torch.float32)
    nb = find_neighbors(x, None, H)
    row_ptr, col = walls.cut_pairs(x, nb.row_ptr, nb.col, [_plate()], IDENTITY, H, native=native)
    rows = nb.rows()
    opposite = (x[rows, 1] > 0) != (x[nb.col, 1] > 0)         # every such segment meets the plate
    expected = _pairs(nb.row_ptr, nb.col) - set(zip(rows[opposite].tolist(), nb.col[opposite].tolist()))
    assert int(opposite.sum()) > 1000
    assert _pairs(row_ptr, col) == expected
    kept = _pairs(row_ptr, col)
    assert all((k, i) in kept for i, k in kept)                # lists stay symmetric


def test_the_rule_misses_no_wall_of_a_tilted_cup():
    """The per-pair rule that picks which pairs to march, against marching every pair."""
    cup = shapes.cup_grid()
    q = torch.tensor([0.0, 0.0, math.sin(0.35), math.cos(0.35)])       # tilted 40° about z
    pose = torch.cat([torch.tensor([0.01, 0.02, 0.0]), q])[None]
    rng = np.random.default_rng(5)
    x = torch.as_tensor(rng.uniform([-0.08, -0.03, -0.06], [0.08, 0.14, 0.06], (60000, 3)), dtype=torch.float32)
    d = min_sdf(x, [cup], pose)
    x = x[(d > 0.0002) & (d < 0.006)][:6000]                    # near the walls, inside and out
    nb = find_neighbors(x, None, H)
    every = walls.pairs_through_walls(x, nb.row_ptr, nb.col, [cup], pose)
    slack = walls.slack_for([cup])
    rule = walls.facing_pairs(x, nb.row_ptr, nb.col, [cup], pose, slack, H)
    assert int(every.sum()) > 500                               # walls between many pairs
    assert not bool((every & ~rule).any())                      # none of them missed
    assert int(rule.sum()) < 1.5 * int(every.sum())             # and few marched for nothing
    cut = walls.cut_pairs(x, nb.row_ptr, nb.col, [cup], pose, H)
    assert _pairs(*cut) == _pairs(nb.row_ptr, nb.col) - set(zip(nb.rows()[every].tolist(), nb.col[every].tolist()))
    if fused.available():
        assert torch.equal(walls.facing_pairs(x, nb.row_ptr, nb.col, [cup], pose, slack, H, native=True), rule)
        native = walls.cut_pairs(x, nb.row_ptr, nb.col, [cup], pose, H, native=True)
        assert torch.equal(native[0], cut[0]) and torch.equal(native[1], cut[1])


def _hanging_drop():
    g = (np.arange(-3, 3) + 0.5) * SP
    top = np.array([[a, 0.0015 + SP / 2 + j * SP, b] for a in g for b in g for j in range(2)])
    gd = np.array([-SP / 2, SP / 2])
    drop = np.array([[a, -0.002 - SP / 2, b] for a in gd for b in gd])   # 0.5 mm under the plate
    return top, drop


@pytest.mark.parametrize("backend", ["torch"] + (["fused"] if fused.available() else []))
def test_a_drop_under_a_plate_falls_freely_only_with_the_cut(backend):
    top, drop = _hanging_drop()
    steps = 18
    free_fall = -9.8 * DT * DT * steps * (steps + 1) / 2       # symplectic Euler from rest
    out = {}
    for cut in (False, True):
        model = FluidModel.create(H, dt=DT, iterations=7, relaxation=4.0, reference_iterations=4, objects=[_plate()],
                                  wall_pairs=not cut, backend=backend)
        s = lt.make_state(np.concatenate([top, drop]), poses=IDENTITY)
        for _ in range(steps):
            s = lt.step(model, s, IDENTITY)
        out[cut] = float(s.by_id()[0][len(top):, 1].mean()) - drop[:, 1].mean()
    assert out[False] > 0.0                                     # held through the plate: it even rises
    assert out[True] == pytest.approx(free_fall, rel=1e-4)      # nothing holds it: free fall


def test_a_step_with_no_pair_across_a_wall_is_unchanged_bit_for_bit():
    cup = shapes.cup_grid()
    g = (np.arange(-3, 3) + 0.5) * SP
    x = np.array([[a, 0.0035 + j * SP, b] for a in g for b in g for j in range(3)])  # a pool inside the cup
    states = []
    for wall_pairs in (True, False):
        model = FluidModel.create(H, dt=DT, iterations=4, objects=[cup], wall_pairs=wall_pairs)
        s = lt.make_state(x, poses=IDENTITY)
        for _ in range(5):
            s = lt.step(model, s, IDENTITY)
        states.append(s)
    assert torch.equal(states[0].x, states[1].x) and torch.equal(states[0].v, states[1].v)


def test_the_step_keeps_its_gradient_with_the_cut():
    """d(mean height)/dλ_c through steps that cut pairs, against central differences (the cut
    set does not change under the small perturbation)."""
    top, drop = _hanging_drop()
    x = np.concatenate([top, drop])

    def height(lam):
        model = FluidModel.create(H, dt=DT, iterations=3, relaxation=4.0, objects=[_plate().to(dtype=torch.float64)],
                                  wall_pairs=False, params={"lambda_c": lam}, backend="torch")
        s = lt.make_state(x, poses=IDENTITY.double(), dtype=torch.float64)
        for _ in range(3):
            s = lt.step(model, s, IDENTITY.double())
        return s.x[:, 1].mean()

    lam = torch.tensor(0.3, dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(height(lam), lam)
    e = 1e-5
    fd = (height(torch.tensor(0.3 + e, dtype=torch.float64)) - height(torch.tensor(0.3 - e, dtype=torch.float64))) / (2 * e)
    assert abs(float(g)) > 1e-6
    assert float(g) == pytest.approx(float(fd), rel=1e-4)


def test_a_scene_spec_and_the_control_tasks_cut_wall_pairs():
    from liquidtwin.generate.catalog import build_setup
    from liquidtwin.generate.world import control_model, model_for
    from liquidtwin.session._build import build_scene
    from liquidtwin_proto import liquidtwin_pb2 as pb
    scene = pb.SceneSpec(name="cup")
    scene.objects.add(name="source", model="cup", container=True, initial_pose=[0, 0, 0, 0, 0, 0, 1])
    scene.objects[0].params["radius"] = 0.03
    scene.fills.add(container="source", volume_ml=10.0)
    scene.simulation.h, scene.simulation.dt, scene.simulation.iterations = H, DT, 4
    assert build_scene(pb.SessionSpec(scene=scene)).model.wall_pairs            # unset: SPNets as published
    scene.simulation.cut_wall_pairs = True
    assert not build_scene(pb.SessionSpec(scene=scene)).model.wall_pairs
    setup = build_setup("plate_tilt", np.random.default_rng(0), quick=True)
    assert not control_model(setup).wall_pairs
    assert model_for(setup).wall_pairs                                           # the tracker's model: unchanged
