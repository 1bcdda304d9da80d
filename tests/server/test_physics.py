"""Physics checks: settling at rest density, conservation, anti-clipping, determinism, bad input."""

import math
import warnings

import numpy as np
import pytest
import torch

import liquidtwin as lt
from liquidtwin.scenes import shapes


def _interior_density(model, x):
    nb = lt.find_neighbors(x, None, model.h)
    rho = lt.convsp(x, torch.ones(len(x), dtype=x.dtype), "rho", model.h, neighbors=nb)
    return rho / model.rest_density


def test_block_settles_at_rest_density_and_stays_stable():
    """Thesis scale (h = 0.1): 1,755 particles in a box, 1,000 steps; pressure only."""
    h = 0.1
    box = shapes.open_box_grid((0.4, 0.4), 1.2, 0.03)
    model = lt.FluidModel.create(h, objects=[box], dt=1 / 120, iterations=4, relaxation=4.0,
                                 params=dict(lambda_c=0.0))
    x = lt.lattice([-0.35, 0.05, -0.35], [0.35, 0.45, 0.35], model.spacing)
    state = lt.make_state(x, poses=torch.tensor([[0, 0, 0, 0, 0, 0, 1.0]]))
    n = len(x)
    for i in range(1000):
        state = lt.step(model, state)
    xs = state.x
    assert xs.shape[0] == n and sorted(state.ids.tolist()) == list(range(n))
    interior = (xs[:, 0].abs() < 0.2) & (xs[:, 2].abs() < 0.2) & (xs[:, 1] > 0.03 + h) & \
        (xs[:, 1] < xs[:, 1].max() - h)
    assert int(interior.sum()) > 20
    ratio = float(_interior_density(model, xs)[interior].mean())
    assert abs(ratio - 1.0) < 0.02, ratio
    assert float(state.v.norm(dim=1).max()) < 0.1  # at rest, no jitter build-up
    assert float(xs[:, 1].min()) > 0.03  # nobody fell through the floor


def _cavity_inside(p, inner_half):
    return bool((np.abs(p) < np.asarray(inner_half)).all())


def test_no_particle_crosses_a_3mm_wall_while_the_container_turns_180_degrees_in_half_a_second():
    h = 0.01
    inner = (0.03, 0.03, 0.03)
    sealed = shapes.sealed_box_grid(inner, 0.003)
    cup = shapes.cup_grid(0.035, 0.08, 0.003)
    for grid, kind in ((sealed, "sealed"), (cup, "cup")):
        model = lt.FluidModel.create(h, objects=[grid])
        if kind == "sealed":
            x = lt.lattice([-0.025] * 3, [0.025, 0.0, 0.025], model.spacing)
            centre = torch.zeros(3)
        else:
            x = lt.lattice([-0.025, 0.006, -0.025], [0.025, 0.05, 0.025], model.spacing)
            x = x[np.linalg.norm(x[:, [0, 2]], axis=1) < 0.03]
            centre = torch.tensor([0.0, 0.04, 0.0])
        steps = 30  # 0.5 s at 60 Hz, 6° per step about an axis through the container
        pose0 = torch.tensor([[0, 0, 0, 0, 0, 0, 1.0]])
        state = lt.make_state(x, poses=pose0)
        for i in range(1, steps + 1):
            angle = math.pi * i / steps
            q = lt.quat_from_axis_angle([0.0, 0.0, 1.0], angle).float()
            R = lt.quat_to_matrix(q)
            t = centre - R @ centre  # rotate about the container centre
            state = lt.step(model, state, torch.cat([t, q])[None])
            local = ((state.x - t) @ R).numpy()
            fn = (lambda p: shapes.sealed_box(p, inner, 0.003)) if kind == "sealed" else \
                (lambda p: shapes.cup(p, 0.035, 0.08, 0.003))
            assert fn(local).min() > -2e-4, (kind, i, fn(local).min())
            if kind == "sealed":
                assert np.all(np.abs(local) < 0.03 + 1e-4), (i, np.abs(local).max())
        assert len(state.x) == len(x)


def test_fixed_seed_gives_identical_results():
    box = shapes.open_box_grid((0.03, 0.03), 0.06, 0.006, cell=0.002)
    runs = []
    for _ in range(2):
        torch.manual_seed(0)
        model = lt.FluidModel.create(0.02, objects=[box])
        x = lt.lattice([-0.02, 0.01, -0.02], [0.02, 0.04, 0.02], model.spacing)
        v = torch.randn(len(x), 3) * 0.1
        s = lt.make_state(x, v, poses=torch.tensor([[0, 0, 0, 0, 0, 0, 1.0]]))
        for _ in range(20):
            s = lt.step(model, s)
        runs.append((s.x.clone(), s.v.clone(), s.ids.clone()))
    assert torch.equal(runs[0][0], runs[1][0]) and torch.equal(runs[0][1], runs[1][1])
    assert torch.equal(runs[0][2], runs[1][2])


def test_extra_terms_plug_in_without_editing_the_step():
    model = lt.FluidModel.create(0.02, gravity=(0, 0, 0))
    x = lt.lattice([0, 0, 0], [0.02, 0.02, 0.02], model.spacing)
    s0 = lt.make_state(x, torch.tensor([[1.0, 0.0, 0.0]]).expand(len(x), 3), dtype=torch.float64)
    k = torch.tensor(3.0, dtype=torch.float64, requires_grad=True)
    dragged = model.replace(terms=(lt.LinearDrag(k),))
    plain = lt.step(model, s0).v[:, 0].mean()
    slow = lt.step(dragged, s0).v[:, 0].mean()
    # a = -k v over one step: v ← v (1 - k dt) before the (momentum-conserving) constraints
    assert float((plain - slow).detach()) == pytest.approx(3.0 * model.dt, rel=1e-6)
    slow.backward()
    assert float(k.grad) == pytest.approx(-model.dt, rel=1e-6)
    wind = model.replace(terms=(lt.UniformAcceleration(torch.tensor([0.0, 0.0, 2.0])),))
    vz = lt.step(wind, s0).v[:, 2].mean()
    assert float(vz) == pytest.approx(2.0 * model.dt, rel=1e-5)


def test_bad_input_raises_clear_errors():
    model = lt.FluidModel.create(0.02)
    with pytest.raises(ValueError, match="empty particle set"):
        lt.make_state(torch.zeros(0, 3))
    x = torch.rand(10, 3) * 0.02
    x[2, 0] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        lt.make_state(x)
    with pytest.raises(ValueError, match="not finite"):
        model.with_params(lambda_v=float("inf"))
    with pytest.raises(ValueError, match="unknown fluid parameters"):
        lt.FluidModel.create(0.02, params=dict(viscosity=1.0))
    box = shapes.open_box_grid((0.03, 0.03), 0.06, 0.006, cell=0.002)
    m2 = lt.FluidModel.create(0.02, objects=[box])
    s = lt.make_state(torch.rand(10, 3) * 0.02, poses=torch.tensor([[0, 0, 0, 0, 0, 0, 1.0]]))
    with pytest.raises(ValueError, match="NaN"):
        lt.step(m2, s, torch.tensor([[0, float("nan"), 0, 0, 0, 0, 1.0]]))
    with pytest.raises(ValueError, match=r"\(1, 7\)"):
        lt.step(m2, s, torch.zeros(2, 7))
    # a state that blows up is reported, never returned as NaN
    wild = model.with_params(lambda_omega=1e38)  # overflows float32
    dense = lt.make_state(torch.rand(200, 3) * 0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(FloatingPointError, match="non-finite"):
            for _ in range(5):
                dense = lt.step(wild, dense)


def _deep_cup_at_rest(iterations: int):
    """A narrow cup 11 cm tall filled to 90 % (~16 rest spacings deep at the generator's h and
    dt), settled, then left alone for 1 s: (mean particle speed over the last 0.5 s, m/s;
    relative change of the settled volume; the fill's report)."""
    from liquidtwin.geometry import build
    from liquidtwin.scenes.fill import fill_container, settled_volume
    cup = build("cup", radius=0.02, bottom_radius=0.016, height=0.11)
    model = lt.FluidModel.create(0.011, objects=[cup.sdf()], dt=1 / 120, iterations=iterations, relaxation=4.0)
    poses = torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)        # a boiling fill may miss its tolerance
        state, report = fill_container(model, poses, 0, cup, fraction=0.9)
    speeds = []
    with torch.no_grad():
        for i in range(120):
            state = lt.step(model, state)
            if i >= 60:
                speeds.append(float(state.v.norm(dim=1).mean()))
    ml = settled_volume(model, state, 0, cup)[0]
    return float(np.mean(speeds)), ml / report.settled_ml - 1.0, report


def test_deep_liquid_stays_at_rest_with_the_generators_solver_iterations():
    """Hydrostatic rest: liquid settled in a container must stay there. The pressure solve
    spreads its correction a few rest spacings per iteration, so deep liquid needs enough
    iterations; with too few the column bounces and boils over, or collapses (SPEC's K = 3 was
    for shallower liquid at h = 0.1). The generator's rule (``generate.world.model_iterations``) gives this
    cup 6; at 4 it does not hold."""
    from liquidtwin.generate.world import MODEL_ITERATIONS
    from liquidtwin.geometry import build
    cup = build("cup", radius=0.02, bottom_radius=0.016, height=0.11)
    depth = cup.height_for_volume(0.9 * cup.capacity_ml) - cup.floor_height
    k = lt.iterations_for_depth(depth, 0.55 * 0.011, least=MODEL_ITERATIONS)
    assert 14 < depth / (0.55 * 0.011) < 18 and k == 6
    speed, change, _ = _deep_cup_at_rest(k)
    assert speed < 0.02 and abs(change) < 0.02, (speed, change)
    speed4, change4, _ = _deep_cup_at_rest(MODEL_ITERATIONS)
    # At 4 the column does not hold. How it fails depends on the CPU's float rounding (the
    # settling is chaotic): it boiled on the machines this was written on (0.37 against
    # 0.004 m/s, −17 % volume) and collapsed on a Sapphire Rapids one (0.010 m/s, −42 %).
    boils = speed4 > 5 * speed and speed4 > 0.05
    collapses = change4 < -0.1 and abs(change4) > 5 * abs(change)
    assert boils or collapses, (speed4, speed, change4, change)



def _impact(iterations: int, speed: float, seed: int) -> tuple[float, float]:
    """A column of liquid (2.4 cm across, 10 cm long) hits the 20 ml resting in a cup at
    ``speed`` m/s (h = 0.011 m, dt = 1/120 s; the same liquid at any count: the cohesion of 4
    iterations). (share of the liquid out of the cup after 0.8 s, fastest upward particle
    speed in that time, m/s)."""
    from liquidtwin.geometry import build
    from liquidtwin.scenes.fill import fill_container
    from liquidtwin.scenes.liquid_level import held
    cup = build("cup")
    poses = torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)

    def model(k):
        return lt.FluidModel.create(0.011, objects=[cup.sdf()], dt=1 / 120, iterations=k, relaxation=4.0,
                                    reference_iterations=4)

    pool, _ = fill_container(model(4), poses, 0, cup, volume_ml=20.0, settle_s=0.3)
    sp, r = model(4).spacing, 0.012
    col = lt.lattice([-r, 0.0, -r], [r, 0.10, r], sp)
    col = col[col[:, 0] ** 2 + col[:, 2] ** 2 <= r ** 2] + [0.0, cup.rim_height + 0.005, 0.0]
    col += np.random.default_rng(seed).uniform(-0.3, 0.3, 3) * sp
    m = model(iterations)
    v = np.concatenate([pool.v.numpy(), np.tile([0.0, -speed, 0.0], (len(col), 1))])
    s = lt.make_state(np.concatenate([pool.x.numpy(), col]), v, poses)
    up = 0.0
    with torch.no_grad():
        for _ in range(96):
            s = lt.step(m, s, poses.to(s.x))
            up = max(up, float(s.v[:, 1].max()))
    return 1.0 - float(np.mean(held(m, s, 0, cup)[0])), up


def test_an_impact_solved_with_too_few_iterations_throws_liquid_back_out():
    """Liquid falling at 2 m/s into a pool moves 2.75 rest spacings into it in one step. The
    pressure solve must undo that overlap within the step; left half solved, the next step
    turns it into velocity: liquid leaves faster than it came (energy from nowhere) and is
    thrown out of the cup. The same liquid (cohesion fixed) solved with
    ``iterations_for_impact``'s count keeps it; with the scenes' 4 it does not. Independent of
    the rule's own measurement (``bench/impact_splash.py``: another cup, column and pool)."""
    speed = 2.0
    k = lt.iterations_for_impact(speed, 1 / 120, 0.55 * 0.011, least=4)
    assert k == 9
    few = np.array([_impact(4, speed, seed) for seed in range(3)])
    enough = np.array([_impact(k, speed, seed) for seed in range(3)])
    # written with: out 1.1-3.4 % at 4 against 0-0.4 % at 9; fastest upward 2.5-7.2 m/s against 1.9-2.3
    assert enough[:, 0].mean() < 0.01 and few[:, 0].mean() > 3 * enough[:, 0].mean() + 0.005, (few, enough)
    assert np.median(enough[:, 1]) < 1.25 * speed < 1.5 * speed < np.median(few[:, 1]), (few, enough)


def test_iterations_for_impact_grows_with_how_far_a_step_moves_into_the_liquid():
    assert lt.iterations_for_impact(0.0, 1 / 120, 0.006, least=4) == 4
    assert lt.iterations_for_impact(2.0, 1 / 120, 0.006) == math.ceil(3 * 2.0 / 120 / 0.006)
    assert lt.iterations_for_impact(2.0, 1 / 240, 0.006) < lt.iterations_for_impact(2.0, 1 / 120, 0.006)
    for bad in ((-1.0, 1 / 120, 0.006), (float("nan"), 1 / 120, 0.006), (1.0, 0.0, 0.006), (1.0, 1 / 120, 0.0)):
        with pytest.raises(ValueError):
            lt.iterations_for_impact(*bad)
