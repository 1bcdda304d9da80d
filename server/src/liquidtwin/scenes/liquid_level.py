"""How much liquid a container holds, read off the particles and the container's geometry.

``settled_volume`` is the container's exact cavity volume below the liquid's free surface
(:meth:`~liquidtwin.geometry.ObjectModel.volume_below_ml`): what a real container holds
when its liquid stands at the same height. It is not the particle count times a nominal
particle volume, because settled PBF liquid packs much denser than the rest lattice (no
boundary particles: particles against walls and floor miss neighbours and the liquid
compresses until their density sums reach the rest density).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..geometry import ObjectModel
from ..sim import FluidModel, FluidState, find_neighbors, quat_to_matrix


def rotation(pose: torch.Tensor) -> np.ndarray:
    """(3, 3) float64 rotation of a (7,) pose (object → world)."""
    return quat_to_matrix(pose[3:].detach().to(torch.float64)).numpy()


def held(model: FluidModel, state: FluidState, index: int,
         obj: ObjectModel) -> tuple[np.ndarray, np.ndarray]:
    """(mask (N,) bool, object-frame positions (N, 3) m) of the particles container ``index``
    (``model.objects[index]``, pose ``state.poses[index]``) holds.

    A particle counts when it is inside the cavity (or up to a spacing above the rim, in the
    opening's column). Particles resting on the inner wall may sit a hair inside the exact
    wall (the simulator works on a sampled SDF), so each is first moved to half a wall from
    the nearest surface along the SDF gradient: towards the cavity from the inner wall, away
    from it from the outer wall.
    """
    pose = state.poses[index].detach().to(torch.float64)
    R = rotation(pose)
    local = (state.x.detach().to(torch.float64).cpu().numpy() - pose[:3].numpy()) @ R
    grid = model.objects[index].to(dtype=torch.float64)
    p = torch.as_tensor(local)
    e = 0.5 * grid.cell
    d = grid.sample_local(p).numpy()
    grad = np.stack([(grid.sample_local(p + e * u) - grid.sample_local(p - e * u)).numpy()
                     for u in torch.eye(3, dtype=torch.float64)], 1)
    grad /= np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
    probe = local + np.clip(0.5 * obj.wall - d, 0.0, obj.wall)[:, None] * grad
    rim = obj.rim_height
    keep = probe[:, 1] <= rim + model.spacing
    probe[:, 1] = np.minimum(probe[:, 1], rim - 1e-9)
    return keep & obj.in_cavity(probe), local


def nearest_spacing(x: np.ndarray, spacing: float) -> float:
    """Median nearest-neighbour distance (m) of points (N, 3) with a neighbour within two
    rest ``spacing`` s (the rest spacing when none has one)."""
    t = torch.as_tensor(x, dtype=torch.float64)
    nb = find_neighbors(t, None, 2.0 * spacing)
    if nb.num_pairs == 0:
        return spacing
    rows = nb.rows()
    d = (t[rows] - t[nb.col]).norm(dim=1)
    best = torch.full((len(t),), math.inf, dtype=torch.float64).scatter_reduce(0, rows, d, "amin")
    return float(best[torch.isfinite(best)].median())


def surface_height(local: np.ndarray, spacing: float) -> float:
    """Height (m) of the free surface of settled particles at positions (N, 3), m.

    The top particles are those with no other particle above them within 0.6 rest
    ``spacing`` horizontally; the surface lies half a layer (√0.75·s/2, s the median
    nearest-neighbour distance) above their mean height. For particles in the rest lattice
    that is exactly the boundary of the volume they stand for.
    """
    squash = torch.tensor([1.0, 1e-4, 1.0], dtype=torch.float64)    # whole columns are near
    nb = find_neighbors(torch.as_tensor(local, dtype=torch.float64) * squash, None, 0.6 * spacing)
    rows, col = nb.rows(), nb.col
    y = torch.as_tensor(local[:, 1])
    covered = torch.zeros(len(local), dtype=torch.bool)
    covered[rows[y[col] > y[rows]]] = True
    top = ~covered.numpy()
    layer = math.sqrt(0.75) * nearest_spacing(local, spacing)
    return float(local[top, 1].mean() + 0.5 * layer)


def settled_volume(model: FluidModel, state: FluidState, index: int, obj: ObjectModel):
    """Liquid container ``index`` holds: (ml, surface height m in the object frame,
    mask (N,) of the held particles). The volume is what the cavity holds below the free
    surface (:func:`surface_height`) of the held particles."""
    mask, local = held(model, state, index, obj)
    n = int(mask.sum())
    if n < 4:
        raise ValueError(f"{obj.name} holds only {n} particles: too few to measure a volume")
    height = min(surface_height(local[mask], model.spacing), obj.rim_height)
    return obj.volume_below_ml(height), height, mask


def marginal_ml(local: np.ndarray, height: float, obj: ObjectModel) -> float:
    """ml per particle in the upper half of the liquid (held particles' object-frame
    positions (N, 3), surface ``height`` m): what one more particle adds, unlike the mean
    it leaves out the compacted layers against the floor."""
    mid = float(np.median(local[:, 1]))
    above = int((local[:, 1] > mid).sum())
    return (obj.volume_below_ml(height) - obj.volume_below_ml(mid)) / max(above, 1)
