"""FluidModel.max_correction: no solver iteration moves a particle further than the cap.

SPNets' pressure is linear in the excess density, so a small blob squeezed well above the
rest density (a falling drop whose particles converge) bursts: one iteration throws a particle
out of its neighbourhood, faster than anything around it. Checked here on a squeezed blob in
free space, against bounds that follow from the cap alone (no collisions: a step's solver move
is at most iterations × cap)."""

import math

import numpy as np
import pytest
import torch

import liquidtwin as lt
from liquidtwin.sim import FluidModel
from liquidtwin.session import EngineError
from liquidtwin.session._build import build_scene
from liquidtwin_proto import liquidtwin_pb2 as pb

H, DT, K = 0.011, 1 / 120, 7


def _blob(squeeze: float, dtype=torch.float32) -> torch.Tensor:
    """A 3×3×3 lattice at ``squeeze`` × the rest spacing, slightly jittered (seeded)."""
    s = 0.55 * H * squeeze
    g = torch.arange(3, dtype=torch.float64) * s
    x = torch.stack(torch.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    x = x + torch.randn(x.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 0.05 * s
    return x.to(dtype)


def _model(cap=None, backend="auto", iterations=K):
    return FluidModel.create(H, dt=DT, iterations=iterations, relaxation=4.0, reference_iterations=4,
                             max_correction=cap, backend=backend)


def _solver_moves(model, x):
    """Each particle's move in one step beyond the free fall it was predicted to make (m), and
    the state after the step."""
    s = lt.step(model, lt.make_state(x))
    predicted = x.double() + DT * DT * torch.tensor(model.gravity, dtype=torch.float64)
    return (s.by_id()[0].double() - predicted).norm(dim=1), s


CAP = 0.5 * 0.55 * H                                          # the control tasks' half spacing


def test_a_squeezed_blob_bursts_without_the_cap_and_not_with_it():
    x = _blob(0.55)                                           # ~6 times the rest density, at rest
    free, s = _solver_moves(_model(), x)
    assert free.max() > H and s.v.norm(dim=1).max() > 2.0    # a particle thrown out of reach at > 2 m/s
    capped, s = _solver_moves(_model(CAP), x)
    assert capped.max() <= K * CAP * (1 + 1e-5)               # the bound the cap implies (no objects)
    assert capped.max() > 0.5 * CAP                           # the blob still moves apart
    assert s.v.norm(dim=1).max() < 0.5
    # one iteration: the step's solver move is at most the cap itself, and is the cap here
    one, _ = _solver_moves(_model(CAP, iterations=1), x)
    assert one.max() == pytest.approx(CAP, rel=1e-4) and one.max() <= CAP * (1 + 1e-5)
    assert _solver_moves(_model(iterations=1), x)[0].max() > 5 * CAP


def test_a_cap_that_no_iteration_reaches_changes_nothing_bit_for_bit():
    x = _blob(0.8)                                            # squeezed a little: corrections under 1.3 mm a step
    a = lt.step(_model(), lt.make_state(x))
    b = lt.step(_model(CAP), lt.make_state(x))
    assert (a.x - x).norm(dim=1).max() > 1e-3                 # the solver does move it
    assert torch.equal(a.x, b.x) and torch.equal(a.v, b.v)


def test_gradients_through_an_engaged_cap_match_finite_differences():
    x0 = _blob(0.7, torch.float64)
    cap = 0.2 * 0.55 * H
    base = _model(cap, backend="torch")

    def f(x, lc):
        s = lt.step(base.with_params(lambda_c=lc), lt.FluidState(x, torch.zeros_like(x), torch.arange(len(x)),
                                                                 torch.zeros(0, 7, dtype=torch.float64)))
        return s.by_id()[0]
    moves, _ = _solver_moves(base, x0)
    assert moves.max() > cap                                  # engaged
    args = (x0.clone().requires_grad_(), torch.tensor(0.1, dtype=torch.float64, requires_grad=True))
    assert torch.autograd.gradcheck(f, args, eps=1e-8, atol=1e-5, rtol=1e-3)


@pytest.mark.parametrize("bad", [0.0, -1e-3, math.nan, math.inf, True, "0.003"])
def test_a_cap_must_be_a_positive_distance(bad):
    with pytest.raises(ValueError, match="max_correction"):
        _model(bad)


def _spec(spacings: float) -> pb.SessionSpec:
    scene = pb.SceneSpec(name="cup")
    scene.objects.add(name="source", model="cup", container=True, initial_pose=[0, 0, 0, 0, 0, 0, 1])
    scene.objects[0].params["radius"] = 0.03
    scene.fills.add(container="source", volume_ml=10.0)
    scene.simulation.h, scene.simulation.dt, scene.simulation.iterations = H, DT, 4
    scene.simulation.max_correction_spacings = spacings
    return pb.SessionSpec(scene=scene)


def test_a_scene_spec_sets_the_cap_in_rest_spacings():
    model = build_scene(_spec(0.5)).model
    assert model.max_correction == pytest.approx(0.5 * model.spacing)
    assert build_scene(_spec(0.0)).model.max_correction is None          # unset: SPNets as published
    with pytest.raises(EngineError, match="max_correction"):
        build_scene(_spec(-0.5))


def test_the_control_tasks_model_caps_half_a_spacing():
    from liquidtwin.generate.catalog import build_setup
    from liquidtwin.generate.world import CONTROL_MAX_CORRECTION_SPACINGS, control_model, model_for
    setup = build_setup("plate_tilt", np.random.default_rng(0), quick=True)
    m = control_model(setup)
    assert CONTROL_MAX_CORRECTION_SPACINGS == 0.5
    assert m.max_correction == pytest.approx(0.5 * m.spacing)
    assert model_for(setup).max_correction is None                       # the tracker's model: unchanged
