"""The torch PBF step (both back ends) against an independent slow NumPy implementation.

~200 particles in an open box whose walls are 4 SDF cells thick; the box slides and tilts a
little every step (pose interpolation and anti-clipping), particles start with velocities
that throw some of them at the walls, and cohesion, surface tension and viscosity are on.
"""

import os
import importlib.util
import math
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

import liquidtwin
from liquidtwin.scenes.shapes import open_box_grid


def _load_reference():
    path = Path(__file__).with_name("numpy_pbf.py")
    name = "liquidtwin_tests_numpy_pbf"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


ref = _load_reference()

H = 0.02
WALL = 0.006  # grid cell WALL / 4: walls are 4 cells thick
HALF = 0.035
STEPS = 3
PARAMS = dict(lambda_omega=1.0, lambda_c=0.05, lambda_s=0.05, lambda_v=20.0)


def _quat_z(angle):
    return [0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2)]


def _quat_x(angle):
    return [math.sin(angle / 2), 0.0, 0.0, math.cos(angle / 2)]


def _mul(q, r):
    x1, y1, z1, w1 = q
    x2, y2, z2, w2 = r
    return [w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2]


def scene():
    """(grid, x0 (N, 3), v0 (N, 3), poses (STEPS + 1, 1, 7)) as float64 numpy."""
    grid = open_box_grid(inner_half_xz=(HALF, HALF), height=0.08, wall=WALL)
    s = 0.55 * H
    lo = np.array([-HALF + 0.5 * s, WALL + 0.5 * s, -HALF + 0.5 * s])
    x = liquidtwin.lattice(lo, lo + np.array([2 * HALF - s, 0.042, 2 * HALF - s]), s)
    rng = np.random.default_rng(7)
    v = rng.normal(scale=0.25, size=x.shape)
    v[::5] += np.array([0.6, -0.4, 0.0])  # some run into the floor and the +x wall
    v[1::7] += np.array([-0.5, 0.0, -0.5])
    poses = []
    for k in range(STEPS + 1):  # slide along x, tilt about z and x, with a non-unit quaternion
        q = np.array(_mul(_quat_z(0.03 * k), _quat_x(-0.02 * k))) * (1.0 + 0.1 * k)
        poses.append([[0.002 * k, -0.001 * k, 0.0015 * k, *q]])
    return grid, x, v, np.array(poses)


def _params(model):
    p = model.params.as_dict()
    return ref.Params(h=model.h, dt=model.dt, gravity=tuple(model.gravity),
                      iterations=model.iterations, kappa=model.kappa,
                      collision_distance=model.collision_distance, relaxation=model.relaxation,
                      damp=model.damp, max_pieces=model.max_pieces,
                      reference_iterations=model.reference_iterations, **p)


def _grid(o):
    g = ref.Grid(o.values.double().numpy(), o.origin.double().numpy(), o.cell, o.thickness)
    # Independent check of the radius; the model's own value (computed in the grid's float32)
    # is used so both sides split moves into the same number of pieces.
    assert g.bounding_radius == pytest.approx(o.bounding_radius, rel=1e-6)
    g.radius = o.bounding_radius
    return g


def run_numpy(model, x, v, poses):
    prm, objects = _params(model), [_grid(o) for o in model.objects]
    stats, out = {}, []
    for k in range(STEPS):
        x, v = ref.step(prm, objects, x, v, poses[k], poses[k + 1], stats)
        out.append((x, v))
    return out, stats


def run_torch(model, x, v, poses, dtype):
    state = liquidtwin.make_state(x, v, poses[0], dtype=dtype)
    out = []
    for k in range(STEPS):
        state = liquidtwin.step(model, state, torch.as_tensor(poses[k + 1], dtype=dtype))
        xs, vs = state.by_id()
        out.append((xs.double().numpy(), vs.double().numpy()))
    return out


def max_diff(a, b):
    dx = max(float(np.abs(xa - xb).max()) for (xa, _), (xb, _) in zip(a, b))
    dv = max(float(np.abs(va - vb).max()) for (_, va), (_, vb) in zip(a, b))
    return dx, dv


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """~200 particles are far too few for a thread pool; on a busy machine its waiting
    threads make the step 50x slower."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def setup():
    grid, x, v, poses = scene()
    model = {b: liquidtwin.FluidModel.create(H, objects=[grid], params=PARAMS, backend=b)
             for b in ("torch", "fused")}
    reference, stats = run_numpy(model["torch"], x, v, poses)
    return model, x, v, poses, reference, stats


def test_scene_exercises_collisions(setup):
    model, x, v, poses, reference, stats = setup
    assert 150 <= x.shape[0] <= 260
    assert stats["pushes"] > 20  # particles were pushed out of the walls
    assert stats["max_pieces"] >= 3  # moves were split into pieces (anti-clipping)
    assert len(stats["piece_counts"]) >= 2  # particles in one move split into different counts
    xs, _ = reference[-1]
    objects = [_grid(o) for o in model["torch"].objects]
    # Nobody crossed a wall: every particle is outside the material (one push-out per piece
    # leaves a small residual at edges, so not necessarily c away) and inside the cavity.
    sdf = ref.min_sdf(xs, objects, poses[-1])
    assert float(sdf.min()) > -0.05 * WALL
    local = ref.to_local(xs, poses[-1][0])
    assert np.all(np.abs(local[:, [0, 2]]) < HALF) and np.all(local[:, 1] > WALL)


@pytest.mark.parametrize("backend", ["torch", "fused"])
def test_float64_matches_numpy(setup, backend):
    model, x, v, poses, reference, _ = setup
    if backend == "fused" and os.environ.get("LIQUIDTWIN_NO_NATIVE") == "1":
        pytest.skip("installed without the C++ extension on purpose")
    got = run_torch(model[backend], x, v, poses, torch.float64)
    dx, dv = max_diff(got, reference)
    assert dx < 1e-10 and dv < 1e-8, (dx, dv)


def test_float32_fused_matches_numpy(setup):
    model, x, v, poses, _, _ = setup
    m = model["fused"] if liquidtwin.sim.fused.available() else model["torch"]
    x32, v32 = x.astype(np.float32).astype(np.float64), v.astype(np.float32).astype(np.float64)
    p32 = poses.astype(np.float32).astype(np.float64)
    reference, _ = run_numpy(m, x32, v32, p32)
    got = run_torch(m, x32, v32, p32, torch.float32)
    dx, dv = max_diff(got, reference)
    assert dx < 1e-5 and dv < 1e-3, (dx, dv)


@pytest.mark.parametrize("backend", ["torch", "fused"])
def test_cohesion_per_step_matches_numpy(backend):
    """``reference_iterations``: 5 iterations whose cohesion and tension add up to 2
    iterations' match the reference; and they do change the step (a K-iteration SPNets step
    applies λ_c K times)."""
    if backend == "fused" and not liquidtwin.sim.fused.available():
        pytest.skip("no C++ extension")
    grid, x, v, poses = scene()
    per_step = liquidtwin.FluidModel.create(H, objects=[grid], params=PARAMS, backend=backend, iterations=5,
                                            reference_iterations=2)
    reference, _ = run_numpy(per_step, x, v, poses)
    dx, dv = max_diff(run_torch(per_step, x, v, poses, torch.float64), reference)
    assert dx < 1e-10 and dv < 1e-8, (dx, dv)
    plain = run_torch(per_step.replace(reference_iterations=None), x, v, poses, torch.float64)
    assert max_diff(plain, reference)[0] > 1e-4
    same = run_torch(per_step.replace(reference_iterations=5), x, v, poses, torch.float64)
    assert max_diff(same, plain) == (0.0, 0.0)
    with pytest.raises(ValueError, match="reference_iterations"):
        liquidtwin.FluidModel.create(H, reference_iterations=0)


if __name__ == "__main__":  # measured differences and timings
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    grid, x, v, poses = scene()
    models = {b: liquidtwin.FluidModel.create(H, objects=[grid], params=PARAMS, backend=b)
              for b in ("torch", "fused")}
    t1 = time.perf_counter()
    reference, stats = run_numpy(models["torch"], x, v, poses)
    t2 = time.perf_counter()
    print(f"N={x.shape[0]} scene {t1 - t0:.2f}s numpy {t2 - t1:.2f}s stats {stats}")
    for b, m in models.items():
        t = time.perf_counter()
        dx, dv = max_diff(run_torch(m, x, v, poses, torch.float64), reference)
        print(f"float64 {b}: max |dx| {dx:.3e} m, max |dv| {dv:.3e} m/s "
              f"({time.perf_counter() - t:.2f}s)")
    x32, v32 = x.astype(np.float32).astype(np.float64), v.astype(np.float32).astype(np.float64)
    p32 = poses.astype(np.float32).astype(np.float64)
    ref32, _ = run_numpy(models["fused"], x32, v32, p32)
    for b, m in models.items():
        dx, dv = max_diff(run_torch(m, x32, v32, p32, torch.float32), ref32)
        print(f"float32 {b}: max |dx| {dx:.3e} m, max |dv| {dv:.3e} m/s")
