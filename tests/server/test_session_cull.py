"""Particles that fall below every object leave the session; the rest are untouched."""

import io

import numpy as np
import torch

from liquidtwin.session._cull import FALL_MARGIN_M, cull_fallen, floor_y
from liquidtwin.sim import FluidState, SDFGrid, quat_from_axis_angle


def _box_grid(half=0.05) -> SDFGrid:
    n = 11
    ax = torch.linspace(-half, half, n, dtype=torch.float64)
    X, Y, Z = torch.meshgrid(ax, ax, ax, indexing="ij")
    values = torch.stack([X.abs(), Y.abs(), Z.abs()]).amax(0) - 0.5 * half
    return SDFGrid(values, torch.full((3,), -half, dtype=torch.float64), 2 * half / (n - 1), 0.01, "box")


def test_floor_is_the_lowest_rotated_corner():
    grid = _box_grid(0.05)
    pose = torch.tensor([0.0, 1.0, 0.0, 0, 0, 0, 1], dtype=torch.float64)
    assert abs(floor_y([grid], pose[None]) - 0.95) < 1e-12
    q = quat_from_axis_angle(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), torch.tensor(np.pi / 4))
    turned = torch.cat([pose[:3], q])[None]
    assert abs(floor_y([grid], turned) - (1.0 - 0.05 * np.sqrt(2))) < 1e-9   # a corner points down


def test_cull_removes_only_fallen_particles_and_keeps_ids():
    grid = _box_grid()
    poses = torch.tensor([[0.0, 0.0, 0.0, 0, 0, 0, 1]], dtype=torch.float64)
    floor = -0.05
    y = torch.tensor([0.0, floor - FALL_MARGIN_M + 1e-3, floor - FALL_MARGIN_M - 1e-3, -18.0, 0.02],
                     dtype=torch.float64)
    x = torch.stack([torch.zeros(5, dtype=torch.float64), y, torch.zeros(5, dtype=torch.float64)], 1)
    ids = torch.tensor([4, 2, 0, 1, 3])
    state = FluidState(x, torch.ones_like(x), ids, poses)
    kept, dropped = cull_fallen(state, [grid])
    assert dropped == 2
    assert kept.ids.tolist() == [4, 2, 3]
    xs, vs = kept.by_id()                     # sparse ids still come out ordered by id
    assert xs[:, 1].tolist() == [float(y[1]), float(y[4]), float(y[0])]
    # a checkpoint of the culled state loads back with weights_only
    buf = io.BytesIO()
    torch.save({"x": kept.x, "ids": kept.ids}, buf)
    buf.seek(0)
    back = torch.load(buf, weights_only=True)
    assert torch.equal(back["ids"], kept.ids)


def test_cull_never_empties_a_session():
    grid = _box_grid()
    poses = torch.tensor([[0.0, 0.0, 0.0, 0, 0, 0, 1]], dtype=torch.float64)
    x = torch.tensor([[0.0, -5.0, 0.0]], dtype=torch.float64)
    state = FluidState(x, torch.zeros_like(x), torch.tensor([0]), poses)
    assert cull_fallen(state, [grid]) == (state, 0)
