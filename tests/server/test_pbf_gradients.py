"""Gradients of the PBF step: fused kernels vs ConvSP reference, and finite differences."""

import os
import pytest
import torch

import liquidtwin as lt
from liquidtwin.scenes import shapes
from liquidtwin.sim import fused, pbf

needs_native = pytest.mark.skipif(os.environ.get("LIQUIDTWIN_NO_NATIVE") == "1",
                                  reason="installed without the C++ extension on purpose")


def _blob(n=40, seed=0, scale=0.035):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 3, generator=g, dtype=torch.float64) * scale


@needs_native
def test_fused_passes_match_convsp_reference_values_and_gradients():
    h = 0.02
    x = _blob(120, 1, 0.06).requires_grad_()
    order, row_ptr, col = fused.sorted_neighbors(x.detach(), h * 1.1)
    xs = x[order]
    nb = lt.Neighbors(row_ptr, col, h * 1.1)
    v = torch.randn(120, 3, dtype=torch.float64, requires_grad=True)
    omega = torch.rand(120, dtype=torch.float64, requires_grad=True)
    nrm_in = torch.randn(120, 3, dtype=torch.float64, requires_grad=True)

    def both(f_fused, f_ref):
        a, b = f_fused(), f_ref()
        for ta, tb in zip(a, b):
            torch.testing.assert_close(ta, tb, rtol=1e-9, atol=1e-9)
        gs = [torch.randn_like(t) for t in a]
        ga = torch.autograd.grad(a, (x, v, omega, nrm_in), gs, allow_unused=True, retain_graph=True)
        gb = torch.autograd.grad(b, (x, v, omega, nrm_in), gs, allow_unused=True, retain_graph=True)
        for ta, tb in zip(ga, gb):
            if ta is None or tb is None:
                assert ta is None or float(ta.abs().max()) == 0
                continue
            torch.testing.assert_close(ta, tb, rtol=1e-8, atol=1e-8)

    both(lambda: [t for i, t in enumerate(fused.density_normals(xs, row_ptr, col, h)) if i != 1],
         lambda: [t for i, t in enumerate(pbf.density_normals(xs, nb, h)) if i != 1])
    count = pbf.density_normals(xs, nb, h)[1]
    both(lambda: fused.pressure_tension(xs, omega, nrm_in, row_ptr, col, h),
         lambda: pbf.pressure_tension(xs, omega, nrm_in, count, nb, h))
    rho = pbf.density_normals(xs, nb, h)[0]
    both(lambda: [fused.viscosity(xs, v, row_ptr, col, h)], lambda: [pbf.viscosity_sum(xs, v, rho, nb, h)])


@needs_native
def test_fused_passes_without_autograd_give_the_recorded_values():
    # with nothing to differentiate the kernels are called directly: the same values, no graph
    h = 0.02
    x = _blob(80, 3, 0.05)
    order, row_ptr, col = fused.sorted_neighbors(x, h * 1.1)
    x = x[order].float()
    v, w, n = torch.randn(80, 3), torch.rand(80), torch.randn(80, 3)
    xg = x.clone().requires_grad_()
    calls = [lambda x: fused.density_normals(x, row_ptr, col, h),
             lambda x: fused.pressure_tension(x, w, n, row_ptr, col, h),
             lambda x: (fused.viscosity(x, v, row_ptr, col, h),)]
    for call in calls:
        recorded = call(xg)
        assert recorded[0].grad_fn is not None
        for ctx in (torch.no_grad(), torch.enable_grad()):       # untracked input, grad on or off
            with ctx:
                direct = call(x)
            assert all(d.grad_fn is None for d in direct)
            for a, b in zip(direct, recorded):
                assert torch.equal(a, b.detach())


@needs_native
def test_fused_passes_gradcheck():
    h = 0.02
    x = _blob(30, 2, 0.04)
    order, row_ptr, col = fused.sorted_neighbors(x, h * 1.1)
    x = x[order].clone().requires_grad_()
    v = torch.randn(30, 3, dtype=torch.float64, requires_grad=True)
    w = torch.rand(30, dtype=torch.float64, requires_grad=True)
    n = torch.randn(30, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: [t for i, t in enumerate(fused.density_normals(x, row_ptr, col, h))
                                               if i != 1], (x,))
    assert torch.autograd.gradcheck(lambda x, w, n: fused.pressure_tension(x, w, n, row_ptr, col, h), (x, w, n))
    assert torch.autograd.gradcheck(lambda x, v: fused.viscosity(x, v, row_ptr, col, h), (x, v))


def _scene(backend, dtype=torch.float64):
    box = shapes.open_box_grid((0.03, 0.03), 0.06, 0.006, cell=0.002).to(dtype=dtype)
    model = lt.FluidModel.create(0.02, objects=[box], backend=backend, params=dict(lambda_s=0.05))
    x = lt.lattice([-0.012, 0.007, -0.012], [0.012, 0.03, 0.012], model.spacing)
    pose0 = torch.tensor([[0, 0, 0, 0, 0, 0, 1.0]], dtype=dtype)
    return model, x, pose0


def _moving_pose(angle, dx):
    q = torch.cat([torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64) * torch.sin(angle / 2),
                   torch.cos(angle / 2).reshape(1)])
    return torch.cat([torch.stack([dx, torch.zeros_like(dx), torch.zeros_like(dx)]), q])[None]


@pytest.mark.parametrize("backend", ["torch", pytest.param("fused", marks=needs_native)])
def test_one_step_gradcheck_params_positions_pose(backend):
    model, x, pose0 = _scene(backend)
    x0 = torch.as_tensor(x, dtype=torch.float64)
    # Seeded: finite differences are only valid away from a contact or neighbour switch. Over
    # 200 unseeded-style draws one (seed 107) put a particle within eps of one; the torch and
    # fused backends then fail alike, so it was the check's, not a gradient's, fault.
    v0 = torch.randn(x0.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 0.05

    def f(x, lv, lc, ls, angle, dx):
        m = model.with_params(lambda_v=lv, lambda_c=lc, lambda_s=ls)
        s = lt.step(m, lt.FluidState(x, v0, torch.arange(len(x)), pose0), _moving_pose(angle, dx))
        xb, vb = s.by_id()
        return xb, vb
    args = (x0.clone().requires_grad_(), *(torch.tensor(v, dtype=torch.float64, requires_grad=True)
                                           for v in (60.0, 0.1, 0.05, 0.05, 0.004)))
    assert torch.autograd.gradcheck(f, args, eps=1e-7, atol=1e-5, rtol=1e-3)


@pytest.mark.parametrize("backend", ["torch", pytest.param("fused", marks=needs_native)])
@pytest.mark.parametrize("checkpointed", [False, True])
def test_five_step_rollout_gradcheck(backend, checkpointed):
    model, x, pose0 = _scene(backend)
    state0 = lt.make_state(x, poses=pose0, dtype=torch.float64)

    def run(lv, lc, angle, checkpoint_steps=checkpointed):
        m = model.with_params(lambda_v=lv, lambda_c=lc)
        poses = torch.cat([_moving_pose(angle * (i + 1) / 5, angle * 0.0)[None] for i in range(5)])
        s, _ = lt.rollout(m, state0, poses, checkpoint_steps=checkpoint_steps, keep=False)
        return s.by_id()[0]
    args = tuple(torch.tensor(v, dtype=torch.float64, requires_grad=True) for v in (60.0, 0.1, 0.3))
    if not checkpointed:
        assert torch.autograd.gradcheck(run, args, eps=1e-7, atol=1e-5, rtol=1e-3)
        return
    # Checkpointed: the full Jacobian costs one recomputing backward per output entry (41 s of
    # the suite on the torch path). Its gradients must be the plain rollout's, which the case
    # above checks in full against finite differences: compared for random cotangents, and a
    # random projection checked against finite differences here too (gradcheck's fast mode).
    gen = torch.Generator().manual_seed(0)
    ya, yb = run(*args), run(*args, checkpoint_steps=False)
    torch.testing.assert_close(ya, yb, rtol=0, atol=0)
    for _ in range(3):
        w = torch.randn(ya.shape, dtype=ya.dtype, generator=gen)
        ga = torch.autograd.grad(ya, args, w, retain_graph=True)
        gb = torch.autograd.grad(yb, args, w, retain_graph=True)
        for a, b in zip(ga, gb):
            torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)
    assert torch.autograd.gradcheck(run, args, eps=1e-7, atol=1e-5, rtol=1e-3, fast_mode=True)


@needs_native
def test_torch_and_fused_steps_agree():
    results = []
    for backend in ("torch", "fused"):
        model, x, pose0 = _scene(backend)
        s = lt.make_state(x, poses=pose0, dtype=torch.float64)
        for i in range(10):
            s = lt.step(model, s, _moving_pose(torch.tensor(0.02 * (i + 1), dtype=torch.float64),
                                               torch.tensor(0.0, dtype=torch.float64)))
        results.append(s.by_id())
    torch.testing.assert_close(results[0][0], results[1][0], rtol=0, atol=1e-9)
    torch.testing.assert_close(results[0][1], results[1][1], rtol=0, atol=1e-7)
