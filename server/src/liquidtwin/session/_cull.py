"""Particles that have left the scene for good: fallen below every object.

Liquid that runs off a table's edge falls without end in the simulation (nothing below
catches it). Such particles cost as much as any other — and more: their speed forces the
neighbour lists to be rebuilt every iteration and stretches the hash grid over metres — yet
can never come back. A session removes them once they are ``FALL_MARGIN_M`` below the
lowest point of every object's SDF box at the current poses; the session reports them as
lost (:attr:`SessionEngine.lost_particles`).
"""

from __future__ import annotations

import torch

from ..sim import FluidState

#: How far below the lowest object a particle must be to be dropped, m.
FALL_MARGIN_M = 0.1


def floor_y(objects, poses: torch.Tensor) -> float:
    """Lowest world y of any object's SDF box corner, m. ``objects``: SDFGrids; ``poses`` (M, 7).

    World y is linear in the local point, y = R[1] · p + t_y, so over the box's corners its
    minimum takes, per axis, the lower of the box's two ends times R[1, a] (float64, no
    tensors: this runs every step)."""
    lowest = float("inf")
    for grid, pose in zip(objects, poses.detach().double().cpu().tolist()):
        qx, qy, qz, qw = pose[3:]
        nn = qx * qx + qy * qy + qz * qz + qw * qw
        row = (2.0 * (qx * qy + qz * qw) / nn, 1.0 - 2.0 * (qx * qx + qz * qz) / nn, 2.0 * (qy * qz - qx * qw) / nn)
        lo = grid.origin.detach().double().cpu().tolist()
        y = pose[1]
        for a in range(3):
            hi = lo[a] + (grid.values.shape[a] - 1) * grid.cell
            y += min(lo[a] * row[a], hi * row[a])
        lowest = min(lowest, y)
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
