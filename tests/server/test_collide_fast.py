"""Fast particle–object collisions: per-object planning, the native no-grad path, the torch path.

References: a re-implementation of the old global anti-clipping scheme (every active particle
against every object, one global piece count from the thinnest wall, the largest sweep and
the longest move), the piece rule recomputed from its statement,
the pure-torch planner, analytic SDFs of the cup, bowl and floor, autograd gradcheck, and the
torch path's autograd gradients for the C++ backward.
"""

import math
import os

import numpy as np
import pytest
import torch

import liquidtwin as lt
from liquidtwin.scenes import shapes
from liquidtwin.sim import collide, fused
from liquidtwin.sim.sdf import _world_to_local, interpolate_poses, push_out, sweep_bound

needs_native = pytest.mark.skipif(os.environ.get("LIQUIDTWIN_NO_NATIVE") == "1",
                                  reason="installed without the C++ extension on purpose")

CUP = dict(radius=0.035, height=0.08, wall=0.003)
BOWL = dict(radius=0.05, wall=0.003)
CUP_AT = torch.tensor([0.0, 0.0, 0.0])
BOWL_AT = torch.tensor([0.13, 0.0, 0.0])
FLOOR_TOP = -0.02


@pytest.fixture(scope="module")
def objects():
    return [shapes.cup_grid(**CUP), shapes.bowl_grid(**BOWL), shapes.floor_grid(half_xz=0.3, depth=0.02, cell=0.005)]


def _turn(angle, about=(0.0, 0.04, 0.0), shift=(0.0, 0.0, 0.0)):
    """Cup pose: rotated by ``angle`` about z through ``about`` (world), then shifted."""
    q = lt.quat_from_axis_angle([0.0, 0.0, 1.0], angle)
    c = torch.tensor(about, dtype=torch.float64)
    t = c - lt.quat_to_matrix(q) @ c + torch.tensor(shift, dtype=torch.float64)
    return torch.cat([t, q])


def _poses(cup_pose):
    ident = torch.tensor([0, 0, 0, 0, 0, 0, 1.0], dtype=torch.float64)
    bowl = ident.clone()
    bowl[:3] = BOWL_AT
    floor = ident.clone()
    floor[1] = FLOOR_TOP
    return torch.stack([cup_pose, bowl, floor])


def _particles(n, seed):
    """Particles inside the cup, near its walls and rim, in and above the bowl, on the floor,
    and some outside every grid box but moving into one (fast, so many pieces)."""
    g = np.random.default_rng(seed)
    k = n // 5
    r = CUP["radius"] * np.sqrt(g.uniform(0, 1, k))
    a = g.uniform(0, 2 * np.pi, k)
    cup = np.stack([r * np.cos(a), g.uniform(0.004, 0.09, k), r * np.sin(a)], 1)
    wall = np.stack([(CUP["radius"] + g.uniform(-0.002, 0.005, k)) * np.cos(a), g.uniform(0.0, 0.09, k),
                     (CUP["radius"] + g.uniform(-0.002, 0.005, k)) * np.sin(a)], 1)
    bowl = np.asarray(BOWL_AT) + g.uniform([-0.05, 0.0, -0.05], [0.05, 0.07, 0.05], (k, 3))
    floor = g.uniform([-0.25, FLOOR_TOP - 0.002, -0.25], [0.25, FLOOR_TOP + 0.01, 0.25], (k, 3))
    far = g.uniform([-0.4, -0.1, -0.4], [0.4, 0.2, 0.4], (n - 4 * k, 3))
    x = np.concatenate([cup, wall, bowl, floor, far])
    v = g.normal(scale=0.6, size=x.shape)
    v[4 * k:] *= 4.0  # outside the grids, heading anywhere at a few m/s
    return torch.as_tensor(x), torch.as_tensor(v / 60.0)


def _scene(objects, dtype, seed=0, n=400, angle=0.35):
    x, delta = _particles(n, seed)
    pa, pb = _poses(_turn(0.0)), _poses(_turn(angle, shift=(0.004, 0.002, 0.0)))
    return x.to(dtype), delta.to(dtype), pa.to(dtype), pb.to(dtype)


def _model(objects, backend="auto", **kw):
    return lt.FluidModel.create(0.01, objects=objects, backend=backend, **kw)


def _old_collide_move(model, x, delta, pose_a, pose_b):
    """The scheme collide_move replaced: one global activity test against the nearest object
    and one piece count for everybody from the thinnest wall and the largest sweep."""
    sweep = float(sweep_bound(model.objects, pose_a, pose_b).max())
    reach = delta.norm(dim=-1)
    bounds = [o.lower_bound_local(_world_to_local(x, pose_a[j])) for j, o in enumerate(model.objects)]
    start = torch.stack(bounds, 0).min(0).values
    margin = model.collision_distance + 2.0 * max(o.cell for o in model.objects)
    active = torch.nonzero(start < reach + sweep + margin).flatten()
    piece = collide.PIECE_FRACTION * min(o.thickness for o in model.objects)
    pieces = max(1, math.ceil((float(reach[active].max()) + sweep) / piece))
    pieces = min(pieces, model.max_pieces)
    xa, da = x[active], delta[active] / pieces
    for s in range(1, pieces + 1):
        pose = pose_b if s == pieces else interpolate_poses(pose_a, pose_b, s / pieces)
        xa = push_out(xa + da, model.objects, pose, model.collision_distance, model._normal_dilation)
    return (x + delta).index_copy(0, active, xa), pieces, active.numel()


def _min_analytic(x, poses):
    """min over cup, bowl and floor of the exact SDFs at world points (N, 3) → (N,) numpy."""
    x = torch.as_tensor(x, dtype=torch.float64)
    fns = [lambda p: shapes.cup(p, **CUP), lambda p: shapes.bowl(p, **BOWL),
           lambda p: shapes.box(p, (0.3, 0.01, 0.3), (0.0, -0.01, 0.0))]
    return np.min([fn(_world_to_local(x, poses[j].double()).numpy()) for j, fn in enumerate(fns)], 0)


@needs_native
@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-6), (torch.float64, 1e-12)])
def test_native_path_matches_torch_path(objects, dtype, tol):
    x, delta, pa, pb = _scene(objects, dtype)
    m = _model(objects)
    plan = collide.plan_collisions(objects, x, delta, pa, pb, m.collision_distance, m.max_pieces, native=True)
    ref = collide.plan_collisions(objects, x, delta, pa, pb, m.collision_distance, m.max_pieces, native=False)
    for a, b in ((plan.idx, ref.idx), (plan.active, ref.active), (plan.pieces, ref.pieces)):
        assert torch.equal(a, b)  # the C++ planner decides exactly as the torch planner
    assert plan.counts == ref.counts
    assert int(plan.pieces[0]) >= 10 and int(plan.pieces[-1]) < int(plan.pieces[0])  # long and short moves
    assert int(plan.active.sum()) < 0.7 * plan.active.numel()  # most particles meet one or two objects
    # Native lower bounds = SDFGrid.lower_bound_local, inside and outside the grid boxes.
    lb_native = collide.lower_bounds(objects, x, pa, native=True)
    lb_torch = collide.lower_bounds(objects, x, pa, native=False)
    torch.testing.assert_close(lb_native, lb_torch, rtol=0, atol=tol)
    for j, o in enumerate(objects):  # many particles lie outside each grid box (clamp + distance)
        lo = o.origin.to(dtype)
        hi = lo + (torch.tensor(o.values.shape, dtype=dtype) - 1) * o.cell
        local = _world_to_local(x, pa[j])
        assert int(((local < lo) | (local > hi)).any(1).sum()) > 50

    with torch.no_grad():
        fast = collide.move_native(objects, x, delta, pa, pb, plan, m.collision_distance, m._normal_dilation)
    slow = collide.move_torch(objects, x, delta, pa, pb, plan, m.collision_distance, m._normal_dilation)
    pushed = ((slow - (x + delta)).norm(dim=1) > 1e-5).sum()
    assert int(pushed) > 40  # the move really hit walls
    assert float((fast - slow).abs().max()) < tol
    # The model entry point takes the native path, with or without gradients (same forward).
    with torch.no_grad():
        torch.testing.assert_close(lt.collide_move(m, x, delta, pa, pb), fast, rtol=0, atol=0)
    xg = x.clone().requires_grad_()
    torch.testing.assert_close(lt.collide_move(m, xg, delta, pa, pb).detach(), fast, rtol=0, atol=0)
    # The torch backend keeps the torch path.
    torch.testing.assert_close(lt.collide_move(_model(objects, backend="torch"), xg, delta, pa, pb).detach(), slow,
                               rtol=0, atol=0)
    # Pose fixed during the move (constraint iterations): the same agreement.
    plan = collide.plan_collisions(objects, x, delta, pb, pb, m.collision_distance, m.max_pieces, native=True)
    a = collide.move_native(objects, x, delta, pb, pb, plan, m.collision_distance, m._normal_dilation)
    b = collide.move_torch(objects, x, delta, pb, pb, plan, m.collision_distance, m._normal_dilation)
    assert float((a - b).abs().max()) < tol


@needs_native
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_plan_skips_only_objects_out_of_reach_even_after_a_push(objects, dtype):
    """The C++ planner reads no SDF corners where a point's distance to an object's grid box
    alone keeps the object out of reach, with the largest push another object could add.
    Points between the turning cup and the bowl, outside both boxes: many reach the bowl
    only through the cup's sweep (the push), and the plan is still the torch planner's."""
    g = np.random.default_rng(5)
    n = 3000
    x = torch.as_tensor(g.uniform([0.0, -0.01, -0.15], [0.26, 0.2, 0.15], (n, 3)), dtype=dtype)
    dirs = torch.as_tensor(g.normal(size=(n, 3)), dtype=dtype)
    delta = dirs / dirs.norm(dim=1, keepdim=True) * torch.as_tensor(g.uniform(0.0, 0.02, (n, 1)), dtype=dtype)
    pa, pb = _poses(_turn(0.0)).to(dtype), _poses(_turn(0.35, shift=(0.004, 0.002, 0.0))).to(dtype)
    m = _model(objects)
    plan = collide.plan_collisions(objects, x, delta, pa, pb, m.collision_distance, m.max_pieces, native=True)
    ref = collide.plan_collisions(objects, x, delta, pa, pb, m.collision_distance, m.max_pieces, native=False)
    for a, b in ((plan.idx, ref.idx), (plan.active, ref.active), (plan.pieces, ref.pieces)):
        assert torch.equal(a, b)
    assert plan.counts == ref.counts
    # what the test rests on: the bowl (fixed, no sweep of its own) taken part in only
    # because the cup's sweep pushes, by points outside its grid box
    sweep = sweep_bound(objects, pa, pb).to(dtype)
    assert float(sweep[0]) > 0 and float(sweep[1]) == 0
    bowl = objects[1]
    lo = bowl.origin.to(dtype)
    hi = lo + (torch.tensor(bowl.values.shape, dtype=dtype) - 1) * bowl.cell
    local = _world_to_local(x, pa[1])
    box = torch.maximum(lo - local, local - hi).clamp(min=0).norm(dim=1)
    reach = delta.norm(dim=1)
    margin = m.collision_distance + 2.0 * bowl.cell
    on_bowl = torch.zeros(n, dtype=torch.bool)
    on_bowl[plan.idx] = plan.active[:, 1]
    pushed_in = on_bowl & (box >= reach + margin)
    assert int(pushed_in.sum()) > 50
    assert int((~on_bowl & (box >= reach + float(sweep[0]) + margin)).sum()) > 500   # skipped


def test_per_object_activity_changes_nothing_against_the_old_global_scheme(objects):
    x, delta, pa, pb = _scene(objects, torch.float64, seed=1)
    model = _model(objects, backend="torch")
    old, pieces, n_old = _old_collide_move(model, x, delta, pa, pb)
    assert pieces >= 10
    assert float((old - (x + delta)).norm(dim=1).max()) > 1e-3  # walls were hit
    for native in [False, True] if fused.available() else [False]:
        plan = collide.plan_collisions(objects, x, delta, pa, pb, model.collision_distance, model.max_pieces,
                                       native=native, pieces=pieces)
        new = collide.move_torch(objects, x, delta, pa, pb, plan, model.collision_distance, model._normal_dilation)
        assert float((new - old).abs().max()) < 1e-12
        # far fewer particle–object evaluations than every active particle against every object
        assert int(plan.active.sum()) < 0.7 * n_old * len(objects)
    # Sized per particle (the default), a particle takes the pieces its own move needs. For
    # those that start outside the material that changes their push-outs very little.
    plan = collide.plan_collisions(objects, x, delta, pa, pb, model.collision_distance, model.max_pieces)
    assert int(plan.pieces.sum()) < 0.5 * pieces * plan.idx.numel()  # 0.28 here
    new = lt.collide_move(model, x, delta, pa, pb)
    outside = torch.as_tensor(_min_analytic(x, pa) > 0)
    assert int(outside.sum()) > 300
    moved = (new - old).norm(dim=1)[outside]
    assert float((moved < 1e-4).double().mean()) > 0.97
    # the rest slid along a curved wall in longer pieces: apart by less than their own piece
    own = torch.zeros(x.shape[0], dtype=x.dtype).index_copy(0, plan.idx, (delta[plan.idx].norm(dim=1) + float(
        sweep_bound(objects, pa, pb).max())) / plan.pieces.to(x.dtype))[outside]
    assert bool((moved <= own + 1e-9).all())


def test_each_particle_takes_the_pieces_its_own_move_needs(objects):
    """The piece rule, recomputed from its statement: particle i takes S_i = max over its
    objects j of ceil((|delta_i| + push_ij + sweep_j) / (wall_j / 3)), push_ij the largest
    sweep of another object i takes part for; both planners give these."""
    x, delta, pa, pb = _scene(objects, torch.float64, seed=2)
    m = _model(objects)
    sweep = sweep_bound(objects, pa, pb).double()
    thin = torch.tensor([o.thickness / 3.0 for o in objects], dtype=torch.float64)
    for native in [False, True] if fused.available() else [False]:
        plan = collide.plan_collisions(objects, x, delta, pa, pb, m.collision_distance, m.max_pieces, native=native)
        want = []
        for r, i in enumerate(plan.idx.tolist()):
            act = plan.active[r]
            need = []
            for j in range(len(objects)):
                if act[j]:
                    push = max([float(sweep[k]) for k in range(len(objects)) if k != j and act[k]], default=0.0)
                    need.append(max(1, math.ceil((float(delta[i].norm()) + push + float(sweep[j])) / float(thin[j]))))
            want.append(max(need))
        assert plan.pieces.tolist() == want
        assert len(set(want)) >= 10 and min(want) == 1  # slow and fast particles in one move


def test_no_particle_enters_a_wall_of_a_fast_turning_cup_on_the_fast_path(objects, monkeypatch):
    """Liquid in a cup that turns 180° in half a second next to a bowl, over a floor."""
    calls = {"native": 0, "torch": 0}
    for name in ("native", "torch"):
        fn = getattr(collide, f"move_{name}")
        monkeypatch.setattr(collide, f"move_{name}",
                            lambda *a, _fn=fn, _n=name, **k: (calls.__setitem__(_n, calls[_n] + 1), _fn(*a, **k))[1])
    model = _model(objects)
    x = lt.lattice([-0.025, 0.006, -0.025], [0.025, 0.05, 0.025], model.spacing)
    x = x[np.linalg.norm(x[:, [0, 2]], axis=1) < 0.03]
    state = lt.make_state(x, poses=_poses(_turn(0.0)))
    worst = np.inf
    with torch.no_grad():
        for i in range(1, 31):
            poses = _poses(_turn(math.pi * i / 30)).float()
            state = lt.step(model, state, poses)
            worst = min(worst, float(_min_analytic(state.x, poses).min()))
    assert worst > -2e-4, worst
    assert len(state.x) == len(x)
    assert float(state.x[:, 1].min()) < 0.0  # liquid left the cup and fell onto the floor
    if fused.available():
        assert calls["native"] > 100 and calls["torch"] == 0
    else:
        assert calls["torch"] > 100


@needs_native
def test_missing_extension_falls_back_to_the_same_result(objects, monkeypatch):
    x, delta, pa, pb = _scene(objects, torch.float32, seed=2, n=200)
    m = _model(objects)
    with torch.no_grad():
        fast = lt.collide_move(m, x, delta, pa, pb)
        monkeypatch.setattr(fused, "_native", None)
        assert not m.use_fused(x)
        slow = lt.collide_move(m, x, delta, pa, pb)
    assert float((fast - slow).abs().max()) < 1e-6


@needs_native
@pytest.mark.parametrize("fixed", [False, True])
# The reference is autograd through the torch path in float64, on the same plan. In float32
# the native gradients are 7.7e-6 to 6.9e-4 of the scale from it, as far as the float32 torch
# path's (1.4e-5 to 6.9e-4; stop 48, fixed and moving poses, this machine). Until stop 48
# the two float32 paths were compared with each other at 1e-4 (9e-5 apart on one Sapphire
# Rapids machine); with per-particle pieces they are 2e-4 apart in one entry, each nearer
# the float64 gradient than that. 2e-3 leaves room for other CPUs' rounding (MKL's AVX-512
# paths round differently); a wrong term is O(1). In float64 the two are 2e-12 of the scale
# apart since the C++ forward samples the grid in a cheaper form than grid_sample (stop 48).
@pytest.mark.parametrize("dtype,tol", [(torch.float32, 2e-3), (torch.float64, 1e-10)])
def test_native_backward_matches_torch_autograd(objects, dtype, tol, fixed):
    """The C++ backward gives the gradients autograd takes through the torch path, for
    positions, moves and both poses, on a move that pushes many particles off walls in many
    pieces (and with the objects fixed, as in the constraint iterations)."""
    x, delta, pa, pb = _scene(objects, dtype, seed=5)
    if fixed:
        pa = pb
    m = _model(objects)
    plan = collide.plan_collisions(objects, x, delta, pa, pb, m.collision_distance, m.max_pieces, native=True)
    assert int(plan.pieces[0]) >= 10
    w = torch.randn(x.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    grads = []
    for move, dt in ((collide.move_torch, torch.float64), (collide.move_native_grad, dtype)):
        xs, ds, pas, pbs = (t.to(dt).clone().requires_grad_() for t in (x, delta, pa, pb))
        if fixed:
            pas = pbs
        out = move(objects, xs, ds, pas, pbs, plan, m.collision_distance, m._normal_dilation)
        (out * w.to(dt)).sum().backward()
        grads.append([g.double() for g in [out.detach(), xs.grad, ds.grad, pbs.grad] + ([] if fixed else [pas.grad])])
    assert float((grads[0][0] - (x + delta)).norm(dim=1).max()) > 1e-3  # walls were hit
    for ref, got in zip(*grads):
        scale = float(ref.abs().max())
        assert scale > 0.1                       # every gradient is really exercised
        assert float((got - ref).abs().max()) <= tol * max(scale, 1.0)
    # The model entry point takes the native backward when a gradient is needed.
    xs = x.clone().requires_grad_()
    out = lt.collide_move(m, xs, delta, pa, pb)
    assert type(out.grad_fn).__name__ == "_CollidePiecesBackward"


def _small_case(backend):
    cup = shapes.cup_grid(**CUP, cell=0.002).to(dtype=torch.float64)
    floor = shapes.floor_grid(half_xz=0.3, depth=0.02, cell=0.005).to(dtype=torch.float64)
    m = _model([cup, floor], backend=backend, collision_distance=0.0015)
    g = torch.Generator().manual_seed(3)
    x = torch.tensor([[0.033, 0.03, 0.0], [0.0, 0.0045, 0.002], [-0.02, 0.05, 0.01], [0.09, FLOOR_TOP + 0.001, 0.0],
                      [0.040, 0.06, 0.0]], dtype=torch.float64)
    delta = torch.tensor([[0.004, -0.001, 0.0], [0.0, -0.002, 0.0], [0.0, -0.001, 0.0], [0.001, -0.002, 0.0],
                          [-0.003, 0.0, 0.001]], dtype=torch.float64) + 1e-4 * torch.randn(5, 3, generator=g,
                                                                                            dtype=torch.float64)
    ident = torch.tensor([0, 0, 0, 0, 0, 0, 1.0], dtype=torch.float64)
    floor_pose = ident.clone()
    floor_pose[1] = FLOOR_TOP
    pa = torch.stack([_turn(0.0), floor_pose])
    pb = torch.stack([_turn(0.05, shift=(0.001, 0.0, 0.0)), floor_pose])
    return m, x, delta, pa, pb


@pytest.mark.parametrize("backend", ["torch", pytest.param("fused", marks=needs_native)])
def test_gradients_positions_moves_and_poses(objects, backend):
    """gradcheck (finite differences) through pieces of different lengths (per-particle pose
    fractions), on the torch path and on the C++ backward."""
    m, x, delta, pa, pb = _small_case(backend)
    plan = collide.plan_collisions(m.objects, x, delta, pa, pb, m.collision_distance, m.max_pieces)
    assert len(set(plan.pieces.tolist())) >= 2  # pieces of different lengths in one move
    moved = lt.collide_move(m, x, delta, pa, pb)
    assert float((moved - (x + delta)).norm(dim=1).max()) > 1e-4  # something was pushed

    def f(x, delta, pa, pb):
        out = lt.collide_move(m, x, delta, pa, pb)
        assert (type(out.grad_fn).__name__ == "_CollidePiecesBackward") == (backend == "fused")
        return out
    args = tuple(t.clone().requires_grad_() for t in (x, delta, pa, pb))
    assert torch.autograd.gradcheck(f, args, eps=1e-7, atol=1e-5, rtol=1e-3)


def test_too_many_pieces_warns_and_caps(objects):
    x, delta, pa, pb = _scene(objects, torch.float32, seed=4, n=100)
    m = _model(objects, max_pieces=4)
    with pytest.warns(RuntimeWarning, match="max_pieces is 4"):
        plan = collide.plan_collisions(objects, x, delta, pa, pb, m.collision_distance, 4, native=fused.available())
    assert int(plan.pieces.max()) == 4
