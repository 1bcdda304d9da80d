"""ConvSDF against analytic SDFs at random poses; gradients w.r.t. positions and poses."""

import numpy as np
import pytest
import torch

import liquidtwin as lt
from liquidtwin.scenes import shapes
from liquidtwin.sim.sdf import COLLISION_OFFSETS, COLLISION_WEIGHTS


def _random_pose(g):
    t = torch.rand(3, generator=g, dtype=torch.float64) * 0.2 - 0.1
    q = torch.randn(4, generator=g, dtype=torch.float64)
    return torch.cat([t, q / q.norm()])


def _analytic_world(fn, p, pose):
    R = lt.quat_to_matrix(pose[3:])
    local = (p - pose[:3]) @ R
    return torch.as_tensor(fn(local.numpy()))


SPHERE = (lambda p: shapes.sphere(p, 0.05), 0.001)
BOX = (lambda p: shapes.box(p, (0.04, 0.02, 0.03)), 0.001)


@pytest.mark.parametrize("shape", [SPHERE, BOX], ids=["sphere", "box"])
def test_convsdf_matches_analytic_at_random_poses(shape):
    fn, cell = shape
    grid = shapes.sample_grid(fn, (-0.07,) * 3, (0.07,) * 3, cell, 0.01, "shape", dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    for _ in range(5):
        pose = _random_pose(g)
        local = torch.rand(400, 3, generator=g, dtype=torch.float64) * 0.12 - 0.06
        p = local @ lt.quat_to_matrix(pose[3:]).T + pose[:3]
        got = lt.min_sdf(p, [grid], pose[None])
        ref = _analytic_world(fn, p, pose)
        # trilinear interpolation error is second order in the cell (and at box edges first order)
        assert float((got - ref).abs().max()) < 0.6 * cell
        # stencil: value row and central differences = analytic gradient away from edges
        out = lt.conv_sdf(p, [grid], pose[None], COLLISION_OFFSETS, COLLISION_WEIGHTS, 0.002)
        torch.testing.assert_close(out[:, 0], got)


def test_sphere_normal_and_push_out():
    grid = shapes.sample_grid(lambda p: shapes.sphere(p, 0.05), (-0.07,) * 3, (0.07,) * 3, 0.002, 0.05, "s",
                              dtype=torch.float64)
    pose = torch.tensor([[0.1, 0.2, -0.1, 0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)
    d = torch.nn.functional.normalize(torch.randn(50, 3, dtype=torch.float64), dim=1)
    p = pose[0, :3] + 0.03 * d  # inside, 2 cm deep
    out = lt.conv_sdf(p, [grid], pose, COLLISION_OFFSETS, COLLISION_WEIGHTS, 0.001)
    n = torch.nn.functional.normalize(out[:, 1:], dim=1)
    assert float((n * d).sum(1).min()) > 0.999
    pushed = lt.push_out(p, [grid], pose, 0.001, 0.001)
    r = (pushed - pose[0, :3]).norm(dim=1)
    assert float((r - 0.051).abs().max()) < 5e-4


def test_points_outside_the_grid_get_a_positive_distance():
    grid = shapes.sample_grid(lambda p: shapes.sphere(p, 0.05), (-0.07,) * 3, (0.07,) * 3, 0.002, 0.05, "s",
                              dtype=torch.float64)
    p = torch.tensor([[1.0, 0.0, 0.0], [0.0, -3.0, 0.0]], dtype=torch.float64)
    pose = torch.tensor([[0, 0, 0, 0, 0, 0, 1.0]], dtype=torch.float64)
    val = lt.min_sdf(p, [grid], pose)
    assert float(val.min()) > 0.9
    lower = grid.lower_bound_local(p)
    assert bool((lower <= torch.tensor([0.95, 2.95], dtype=torch.float64)).all())


def test_gradcheck_positions_and_pose_including_rotation():
    fn = lambda p: shapes.box(p, (0.04, 0.02, 0.03))
    grid = shapes.sample_grid(fn, (-0.07,) * 3, (0.07,) * 3, 0.004, 0.01, "box", dtype=torch.float64)
    g = torch.Generator().manual_seed(5)
    pose = _random_pose(g)
    p = (torch.rand(30, 3, generator=g, dtype=torch.float64) * 0.08 - 0.04 + pose[:3]).requires_grad_()
    pose = pose[None].clone().requires_grad_()
    w = torch.randn(4, 7, dtype=torch.float64)

    def f(p, pose):
        return lt.conv_sdf(p, [grid], pose, COLLISION_OFFSETS, w, 0.002)
    # Trilinear is piecewise smooth: keep finite-difference steps inside one cell.
    assert torch.autograd.gradcheck(f, (p, pose), eps=1e-7, atol=1e-5)


def test_rotation_gradient_matches_analytic_derivative():
    """d SDF / d angle for a rotating box equals the analytic value (the original SPNets bug)."""
    fn = lambda p: shapes.box(p, (0.04, 0.02, 0.03))
    grid = shapes.sample_grid(fn, (-0.07,) * 3, (0.07,) * 3, 0.001, 0.01, "box", dtype=torch.float64)
    angle = torch.tensor(0.3, dtype=torch.float64, requires_grad=True)
    axis = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    q = torch.cat([axis * torch.sin(angle / 2), torch.cos(angle / 2).reshape(1)])
    pose = torch.cat([torch.zeros(3, dtype=torch.float64), q])[None]
    p = torch.tensor([[0.055, 0.01, 0.0]], dtype=torch.float64)  # outside the +x face
    lt.min_sdf(p, [grid], pose).sum().backward()
    # local point = R(-a) p; sdf = local_x - 0.04 ⇒ d/da = d/da (cos a px + sin a py) = -sin a px + cos a py
    expected = -np.sin(0.3) * 0.055 + np.cos(0.3) * 0.01
    assert abs(float(angle.grad) - expected) < 2e-3


def test_degenerate_objects_and_poses_are_rejected():
    with pytest.raises(ValueError, match="no inside"):
        lt.SDFGrid(torch.ones(4, 4, 4), torch.zeros(3), 0.01, 0.01, "air")
    with pytest.raises(ValueError, match="non-finite"):
        lt.SDFGrid(torch.full((4, 4, 4), float("nan")), torch.zeros(3), 0.01, 0.01)
    with pytest.raises(ValueError, match="3-D"):
        lt.SDFGrid(-torch.ones(4, 4), torch.zeros(3), 0.01, 0.01)
    from liquidtwin.sim.sdf import check_poses
    with pytest.raises(ValueError, match="NaN"):
        check_poses(torch.tensor([[0, 0, float("nan"), 0, 0, 0, 1.0]]), 1)
    with pytest.raises(ValueError, match="zero norm"):
        check_poses(torch.zeros(1, 7), 1)


def test_per_object_set_cache_is_by_identity_and_dies_with_its_objects():
    import gc
    import weakref

    from liquidtwin.sim.sdf import cached_for
    a = shapes.open_box_grid((0.03, 0.03), 0.06, 0.006, cell=0.004)
    b = shapes.open_box_grid((0.03, 0.03), 0.06, 0.006, cell=0.004)
    made = []

    def make():
        made.append(1)
        return object()
    first = cached_for((a, b), "k", make)
    assert cached_for((a, b), "k", make) is first and len(made) == 1      # made once
    assert cached_for((b, a), "k", make) is not first                       # another set (order counts)
    assert cached_for((a, b), "other", make) is not first and len(made) == 3
    gone = weakref.ref(b)
    del b
    gc.collect()
    assert gone() is not None          # a's entries keep b: its id cannot be reused meanwhile
    gone_a = weakref.ref(a)
    del a
    gc.collect()
    assert gone_a() is None and gone() is None   # nothing module-level keeps either alive
