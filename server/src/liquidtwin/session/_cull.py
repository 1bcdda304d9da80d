"""Particles that have left the scene for good: fallen below every object.

Liquid that runs off a table's edge falls without end in the simulation (nothing below
catches it). Such particles cost as much as any other — and more: their speed forces the
neighbour lists to be rebuilt every iteration and stretches the hash grid over metres — yet
can never come back. A session removes them once they are ``FALL_MARGIN_M`` below the
lowest point of every object's SDF box at the current poses; the session reports them as
lost (:attr:`SessionEngine.lost_particles`).
"""

from __future__ import annotations

import itertools

import torch

from ..sim import FluidState, quat_to_matrix

#: How far below the lowest object a particle must be to be dropped, m.
FALL_MARGIN_M = 0.1


def floor_y(objects, poses: torch.Tensor) -> float:
    """Lowest world y of any object's SDF box corner, m. ``objects``: SDFGrids; ``poses`` (M, 7)."""
    lowest = float("inf")
    for grid, pose in zip(objects, poses):
        lo = grid.origin.to(pose)
        hi = lo + (torch.tensor(grid.values.shape, dtype=pose.dtype, device=pose.device) - 1) * grid.cell
        corners = torch.stack([torch.stack([(lo, hi)[b][a] for a, b in enumerate(bits)])
                               for bits in itertools.product((0, 1), repeat=3)])
        world = corners @ quat_to_matrix(pose[3:]).T + pose[:3]
        lowest = min(lowest, float(world[:, 1].min()))
    return lowest


def cull_fallen(state: FluidState, objects) -> tuple[FluidState, int]:
    """``state`` without particles more than FALL_MARGIN_M below every object; how many went."""
    if not objects:
        return state, 0
    keep = state.x[:, 1] >= floor_y(objects, state.poses) - FALL_MARGIN_M
    dropped = int((~keep).sum())
    if dropped == 0 or dropped == keep.numel():   # never empty a session: the step needs particles
        return state, 0
    return state.subset(keep), dropped
