"""Neighbour search and ConvSP against brute-force O(N²) references."""

import os
import math

import pytest
import torch

import liquidtwin as lt
from liquidtwin.sim import fused
from liquidtwin.sim.fused import _native
from liquidtwin.sim.neighbors import cell_order, find_neighbors
from liquidtwin.sim.kernels import kernel_value


def _pairs(nb):
    return set(zip(nb.rows().tolist(), nb.col.tolist()))


@pytest.mark.parametrize("seed", range(4))
def test_neighbors_match_brute_force(seed):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(700, 3, generator=g, dtype=torch.float64) * 0.3 - 0.1
    x[:5] += torch.tensor([50.0, -3e3, 7.0], dtype=torch.float64)  # far from the others
    x[5:9] = x[10]  # coincident points
    r = 0.037
    assert _pairs(lt.find_neighbors(x, None, r)) == _pairs(lt.brute_force_neighbors(x, None, r))
    q = torch.rand(90, 3, generator=g, dtype=torch.float64) * 0.3 - 0.1
    assert _pairs(lt.find_neighbors(q, x, r)) == _pairs(lt.brute_force_neighbors(q, x, r))


@pytest.mark.skipif(os.environ.get("LIQUIDTWIN_NO_NATIVE") == "1", reason="installed without the C++ extension on purpose")
def test_native_neighbors_match_brute_force():
    g = torch.Generator().manual_seed(7)
    x = torch.rand(900, 3, generator=g) * 0.2
    x[0] = torch.tensor([1e4, 1e4, -1e4])
    order, row_ptr, col = fused.sorted_neighbors(x, 0.03)
    assert sorted(order.tolist()) == list(range(900))
    xs = x[order]
    got = set()
    for i in range(900):
        got |= {(i, int(j)) for j in col[row_ptr[i]:row_ptr[i + 1]]}
    assert got == _pairs(lt.brute_force_neighbors(xs, None, 0.03))
    keys = torch.floor(xs / 0.03)
    # sorted by cell: equal cells are contiguous
    changes = (keys[1:] != keys[:-1]).any(1).sum()
    assert int(changes) + 1 == len(torch.unique(keys, dim=0))


@pytest.mark.skipif(os.environ.get("LIQUIDTWIN_NO_NATIVE") == "1", reason="installed without the C++ extension on purpose")
@pytest.mark.parametrize("seed", range(3))
def test_native_dense_grid_and_ranked_cells_give_the_same_lists(seed):
    """The dense-grid path (a compact cloud) and the ranked-cell path (forced with
    max_dense=0, the one a far-away point takes) give the same order and lists, bit for bit,
    and both match brute force; a cloud with a far point takes the ranked path unforced."""
    g = torch.Generator().manual_seed(seed)
    r = 0.021
    x = torch.rand(1500, 3, generator=g, dtype=torch.float64) * torch.tensor([0.3, 0.1, 0.2], dtype=torch.float64) - 0.05
    x[7:11] = x[20]  # coincident points
    x[30] = x[31] + torch.tensor([r, 0.0, 0.0], dtype=torch.float64)  # exactly r apart: not a pair
    dense = fused.sorted_neighbors(x, r)
    ranked = _native.sorted_neighbors(x, r, 0)
    assert all(torch.equal(a, b) for a, b in zip(dense, ranked))
    order, row_ptr, col = dense
    xs = x[order]
    got = {(i, int(j)) for i in range(len(x)) for j in col[row_ptr[i]:row_ptr[i + 1]]}
    assert got == _pairs(lt.brute_force_neighbors(xs, None, r))
    far = torch.cat([x, torch.full((1, 3), 1e3, dtype=torch.float64)])  # a ~1e14-cell box; sorts last
    order_f, row_ptr_f, col_f = fused.sorted_neighbors(far, r)
    assert order_f[-1] == len(x) and torch.equal(order_f[:-1], order)
    assert torch.equal(row_ptr_f[:-1], row_ptr) and torch.equal(col_f, col)


@pytest.mark.parametrize("native", [True, False])
def test_listing_sorted_points_again_gives_the_identity_and_the_same_lists(native):
    """The PBF step's first solver iteration reuses the lists of the positions just sorted
    (``pbf.step``): that holds because sorting already sorted points is the identity (the cell
    sort is stable) and their lists come out the same, on both search paths and precisions."""
    if native and os.environ.get("LIQUIDTWIN_NO_NATIVE") == "1":
        pytest.skip("installed without the C++ extension on purpose")
    g = torch.Generator().manual_seed(4)
    r = 0.021
    for dtype in (torch.float32, torch.float64):
        x = (torch.rand(1200, 3, generator=g, dtype=torch.float64) * 0.12).to(dtype)
        x[5:9] = x[40]                                   # coincident points share a cell
        if native:
            for max_dense in (-1, 0):                    # dense grid and ranked cells
                order, row_ptr, col = _native.sorted_neighbors(x, r, max_dense)
                again = _native.sorted_neighbors(x[order], r, max_dense)
                assert torch.equal(again[0], torch.arange(len(x)))
                assert torch.equal(again[1], row_ptr) and torch.equal(again[2], col)
        else:
            xs = x[cell_order(x, r)]
            assert torch.equal(cell_order(xs, r), torch.arange(len(x)))
            a, b = find_neighbors(xs, None, r), find_neighbors(xs[cell_order(xs, r)], None, r)
            assert torch.equal(a.row_ptr, b.row_ptr) and torch.equal(a.col, b.col)


@pytest.mark.skipif(os.environ.get("LIQUIDTWIN_NO_NATIVE") == "1", reason="installed without the C++ extension on purpose")
def test_native_neighbors_across_empty_cells_and_thread_counts():
    """Clusters a cell or two apart on every axis (neighbour cells that do and do not exist,
    as in a stream), against brute force; the same lists on 1 and 2 threads."""
    g = torch.Generator().manual_seed(3)
    r = 0.02
    centres = torch.tensor([[a, b, c] for a in (0, 2, 3, 6) for b in (0, 2, 5) for c in (0, 1, 4)], dtype=torch.float64)
    x = (centres[:, None, :] * r + torch.rand(len(centres), 40, 3, generator=g, dtype=torch.float64) * 1.6 * r).reshape(-1, 3)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = fused.sorted_neighbors(x, r)
        torch.set_num_threads(2)
        two = fused.sorted_neighbors(x, r)
    finally:
        torch.set_num_threads(threads)
    assert all(torch.equal(a, b) for a, b in zip(one, two))
    order, row_ptr, col = one
    xs = x[order]
    got = {(i, int(j)) for i in range(len(x)) for j in col[row_ptr[i]:row_ptr[i + 1]]}
    assert got == _pairs(lt.brute_force_neighbors(xs, None, r))


def test_single_particle_and_empty_queries():
    x = torch.zeros(1, 3)
    assert lt.find_neighbors(x, None, 0.1).num_pairs == 0
    assert lt.find_neighbors(torch.zeros(0, 3), x, 0.1).row_ptr.tolist() == [0]


def test_bad_positions_are_rejected():
    x = torch.rand(10, 3)
    x[3, 1] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        lt.find_neighbors(x, None, 0.1)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        lt.find_neighbors(torch.rand(10, 2), None, 0.1)


def _brute_convsp(q, d, y, kernel, h, dis_norm=False, same=True):
    diff = q[:, None, :] - d[None, :, :]
    dist = diff.norm(dim=-1)
    w = kernel_value(kernel, dist, h)
    if same:
        w = w * (1 - torch.eye(len(q), dtype=q.dtype))
    if dis_norm:
        w = torch.where(dist > 0, w / dist.clamp_min(1e-30), torch.zeros_like(w))
    return w @ y


@pytest.mark.parametrize("kernel", lt.KERNELS)
def test_convsp_matches_brute_force(kernel):
    g = torch.Generator().manual_seed(1)
    x = torch.rand(300, 3, generator=g, dtype=torch.float64) * 0.25
    y = torch.randn(300, 5, generator=g, dtype=torch.float64)
    h = 0.06
    for dis_norm in (False, True):
        out = lt.convsp(x, y, kernel, h, dis_norm=dis_norm)
        ref = _brute_convsp(x, x, y, kernel, h, dis_norm)
        torch.testing.assert_close(out, ref, rtol=1e-10, atol=1e-8)
    q = torch.rand(40, 3, generator=g, dtype=torch.float64) * 0.25
    torch.testing.assert_close(lt.convsp(q, y, kernel, h, data=x), _brute_convsp(q, x, y, kernel, h, same=False),
                               rtol=1e-10, atol=1e-8)


def test_convsp_include_self_and_layer_weights():
    x = torch.rand(50, 3, dtype=torch.float64) * 0.1
    y = torch.randn(50, 2, dtype=torch.float64)
    h = 0.05
    with_self = lt.convsp(x, y, "rho", h, include_self=True)
    torch.testing.assert_close(with_self - lt.convsp(x, y, "rho", h), y * 15 / (math.pi * h**3))
    layer = lt.ConvSP(2, 3, "poly6", h).double()
    with torch.no_grad():
        layer.weight.copy_(torch.randn(3, 2))
        layer.bias.copy_(torch.randn(3))
    out = layer(x, y)
    torch.testing.assert_close(out, lt.convsp(x, y, "poly6", h) @ layer.weight.T + layer.bias)


def test_convsp_gradcheck_positions_queries_features_weights():
    g = torch.Generator().manual_seed(3)
    x = (torch.rand(25, 3, generator=g, dtype=torch.float64) * 0.12).requires_grad_()
    q = (torch.rand(8, 3, generator=g, dtype=torch.float64) * 0.12).requires_grad_()
    y = torch.randn(25, 2, generator=g, dtype=torch.float64, requires_grad=True)
    layer = lt.ConvSP(2, 2, "cohesion", 0.06, dis_norm=True).double()
    nb = lt.find_neighbors(q.detach(), x.detach(), 0.06)
    w, b = layer.weight, layer.bias

    def f(q, x, y, w, b):
        s = lt.convsp(q, y, "cohesion", 0.06, data=x, neighbors=nb, dis_norm=True)
        return s @ w.T + b
    assert torch.autograd.gradcheck(f, (q, x, y, w, b))
    for kernel in ("rho", "omega", "spiky", "poly6"):
        nb2 = lt.find_neighbors(x.detach(), None, 0.06)
        assert torch.autograd.gradcheck(lambda x, y: lt.convsp(x, y, kernel, 0.06, neighbors=nb2), (x, y))
