"""Demo scene: a cup pours into a bowl (real sizes, SI units, y up).

Objects (in this order): ``cup`` (inner radius 3.75 cm, 11 cm tall, 3 mm walls), ``bowl``
(hemispherical, 16 cm wide, 3 mm walls) and ``floor`` (a 90 cm slab with its top at y = 0
and a 3 cm rim, so that splashes stay on the table instead of sliding off it). The
cup starts upright, held beside and above the bowl, filled with ~175 ml of liquid packed at
rest density. It tilts about the world z axis around its pouring lip, holds, and returns
upright; bowl and floor stay put.

>>> scene = build_pour_scene()
>>> final, _ = rollout(scene.model, scene.state, scene.poses, keep=False)
>>> liquid_volumes(scene.model, final, scene.containers)  # {"cup": …, "bowl": …, "spilled": …}
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..sim import FluidModel, FluidState, lattice, make_state, quat_from_axis_angle, quat_to_matrix
from . import shapes

# ------------------------------------------------------------------ geometry (m)

CUP_RADIUS = 0.0375
CUP_HEIGHT = 0.11
BOWL_RADIUS = 0.077          # inner; 16 cm wide outside with the wall
WALL = 0.003
H = 0.011                    # kernel radius; rest spacing 0.55 h ≈ 6 mm
DT = 1.0 / 120.0
FILL_ML = 175.0
FLOOR_HALF = 0.45            # floor slab: 90 cm square, 4 cm thick, rim 2 cm wide, 3 cm high
FLOOR_DEPTH = 0.04
FLOOR_RIM = 0.02
FLOOR_RIM_HEIGHT = 0.03

OBJECT_NAMES = ("cup", "bowl", "floor")


@dataclass(frozen=True)
class Trajectory:
    """Scripted cup motion: hold upright, tilt about z around the lip, hold, return, rest.

    The tilt is a cosine ease between poses; angles in degrees, times in s. The lip on the
    pouring (−x) side is the pivot and stays at ``lip`` (world, m) throughout.
    """

    lip: tuple[float, float, float] = (0.03, 0.20, 0.0)
    tilt_deg: float = 115.0
    t_start: float = 0.3
    t_tilt: float = 2.0
    t_hold: float = 1.2
    t_return: float = 1.0

    @property
    def duration(self) -> float:
        """Time at which the cup is back upright, s."""
        return self.t_start + self.t_tilt + self.t_hold + self.t_return

    def angle(self, t: float) -> float:
        """Tilt angle at time t, rad (positive tips the opening towards −x)."""
        s = t - self.t_start
        if s <= 0:
            f = 0.0
        elif s < self.t_tilt:
            f = 0.5 - 0.5 * math.cos(math.pi * s / self.t_tilt)
        elif s < self.t_tilt + self.t_hold:
            f = 1.0
        elif s < self.t_tilt + self.t_hold + self.t_return:
            f = 0.5 + 0.5 * math.cos(math.pi * (s - self.t_tilt - self.t_hold) / self.t_return)
        else:
            f = 0.0
        return math.radians(self.tilt_deg) * f

    def cup_pose(self, t: float) -> torch.Tensor:
        """(7,) float64 pose of the cup at time t: rotation about z around the lip."""
        theta = self.angle(t)
        q = quat_from_axis_angle([0.0, 0.0, 1.0], theta)
        pivot = torch.tensor([-(CUP_RADIUS + WALL), CUP_HEIGHT, 0.0], dtype=torch.float64)
        rot = quat_to_matrix(q)
        trans = torch.tensor(self.lip, dtype=torch.float64) - rot @ pivot
        return torch.cat([trans, q])


def floor(p: np.ndarray) -> np.ndarray:
    """SDF of the floor: a slab with its top face at y = 0 and a low rim round its edge."""
    outer = shapes.box(p, (FLOOR_HALF, 0.5 * (FLOOR_DEPTH + FLOOR_RIM_HEIGHT), FLOOR_HALF),
                       (0.0, 0.5 * (FLOOR_RIM_HEIGHT - FLOOR_DEPTH), 0.0))
    inner = FLOOR_HALF - FLOOR_RIM
    cavity = shapes.box(p, (inner, FLOOR_RIM_HEIGHT, inner), (0.0, FLOOR_RIM_HEIGHT, 0.0))
    return np.maximum(outer, -cavity)


def floor_grid(cell: float = 0.005):
    """:func:`floor` sampled on a grid (its thinnest part is the 2 cm rim)."""
    m = 2 * cell
    return shapes.sample_grid(floor, (-FLOOR_HALF - m, -FLOOR_DEPTH - m, -FLOOR_HALF - m),
                              (FLOOR_HALF + m, FLOOR_RIM_HEIGHT + m, FLOOR_HALF + m), cell,
                              min(FLOOR_RIM, FLOOR_DEPTH), "floor")


# ------------------------------------------------------------------ containers and volumes

@dataclass(frozen=True)
class Container:
    """An open container whose liquid we measure: an analytic cavity test in its own frame.

    Attributes:
      name: label in the volume table.
      index: the object's index in ``model.objects`` (its pose is ``state.poses[index]``).
      kind: ``"cup"`` (cylinder) or ``"bowl"`` (hemisphere), as in :mod:`.shapes`.
      radius: inner radius, m.
      wall: wall thickness, m.
      height: outer height of a cup, m (unused for a bowl).
    """

    name: str
    index: int
    kind: str
    radius: float
    wall: float
    height: float = 0.0

    def contains(self, local: np.ndarray) -> np.ndarray:
        """(N,) bool: object-frame points (N, 3) inside the outer shape's bounding volume,
        above the container's floor, below its rim plane and not inside the wall."""
        outer = self.radius + self.wall
        if self.kind == "cup":
            r = np.linalg.norm(local[:, [0, 2]], axis=1)
            inside = (r < outer) & (local[:, 1] > self.wall) & (local[:, 1] <= self.height)
            return inside & (shapes.cup(local, self.radius, self.height, self.wall) > 0)
        if self.kind == "bowl":
            c = np.array([0.0, outer, 0.0])
            inside = (np.linalg.norm(local - c, axis=1) < outer) & (local[:, 1] <= c[1])
            return inside & (shapes.bowl(local, self.radius, self.wall) > 0)
        raise ValueError(f"unknown container kind {self.kind!r}")


def _world_to_local(x: np.ndarray, pose: np.ndarray) -> np.ndarray:
    rot = quat_to_matrix(torch.as_tensor(pose[3:], dtype=torch.float64)).numpy()
    return (x - pose[:3]) @ rot           # rows: R^T (x - t)


def liquid_volumes(model: FluidModel, state: FluidState, containers) -> dict[str, float]:
    """Liquid in each container and outside all of them (``"spilled"``), ml.

    Each particle counts once (first container that holds it) for ``model.particle_volume``,
    so this is the liquid's rest volume (its mass), not the space it takes: settled liquid
    in this step packs ~20 % above rest density and stands lower than this volume would.
    """
    x = state.x.detach().to(torch.float64).cpu().numpy()
    poses = state.poses.detach().to(torch.float64).cpu().numpy()
    ml = model.particle_volume * 1e6
    free = np.ones(x.shape[0], bool)
    out = {}
    for c in containers:
        hit = free & c.contains(_world_to_local(x, poses[c.index]))
        free &= ~hit
        out[c.name] = float(hit.sum()) * ml
    out["spilled"] = float(free.sum()) * ml
    return out


# ------------------------------------------------------------------ the scene

@dataclass(frozen=True)
class PourScene:
    """Everything the demo needs: model, initial state, poses per step, containers."""

    model: FluidModel
    state: FluidState
    poses: torch.Tensor               # (T, M, 7): object poses at the end of each step
    containers: tuple[Container, ...]
    names: tuple[str, ...]
    trajectory: Trajectory

    @property
    def steps(self) -> int:
        return self.poses.shape[0]


def fill_cup(spacing: float, target_ml: float, margin: float | None = None) -> np.ndarray:
    """(N, 3) rest-lattice particles in the upright cup's cavity (cup frame), ≈ target_ml.

    The lattice is clipped by the analytic cup SDF with ``margin`` (default half a spacing)
    and cut at the fill height whose particle count best matches the target volume.
    """
    margin = 0.5 * spacing if margin is None else margin
    r = CUP_RADIUS
    pts = lattice([-r, WALL, -r], [r, CUP_HEIGHT, r], spacing)
    keep = shapes.cup(pts, CUP_RADIUS, CUP_HEIGHT, WALL) > margin
    keep &= np.linalg.norm(pts[:, [0, 2]], axis=1) < r - margin
    keep &= pts[:, 1] < CUP_HEIGHT - margin
    pts = pts[keep]
    per = 0.75 * spacing**3 * 1e6
    want = int(round(target_ml / per))
    levels = np.unique(np.round(pts[:, 1], 9))
    counts = np.array([(pts[:, 1] <= y + 1e-9).sum() for y in levels])
    level = levels[int(np.argmin(np.abs(counts - want)))]
    return pts[pts[:, 1] <= level + 1e-9]


def build_pour_scene(*, seconds: float | None = None, particles_scale: float = 1.0,
                     fill_ml: float = FILL_ML, backend: str = "auto",
                     trajectory: Trajectory | None = None, dtype=torch.float32) -> PourScene:
    """Build the cup→bowl pour.

    Args:
      seconds: simulated time (default: the trajectory plus 0.7 s to settle).
      particles_scale: multiplies the particle count (h shrinks by its cube root) at the
        same liquid volume.
      fill_ml: liquid initially in the cup, ml.
      backend: ``FluidModel`` back end ("auto", "torch", "fused").
    """
    if not particles_scale > 0:
        raise ValueError(f"particles_scale must be > 0, got {particles_scale}")
    traj = Trajectory() if trajectory is None else trajectory
    seconds = traj.duration + 0.7 if seconds is None else float(seconds)
    steps = max(1, int(round(seconds / DT)))
    h = H / particles_scale ** (1.0 / 3.0)

    cell = WALL / 4.0
    objects = [shapes.cup_grid(CUP_RADIUS, CUP_HEIGHT, WALL, cell=cell),
               shapes.bowl_grid(BOWL_RADIUS, WALL, cell=cell),
               floor_grid()]
    model = FluidModel.create(h, objects=objects, dt=DT, iterations=4, relaxation=4.0,
                              backend=backend)

    def poses_at(t: float) -> torch.Tensor:
        ident = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
        return torch.stack([traj.cup_pose(t), ident, ident])

    p0 = poses_at(0.0)
    local = fill_cup(model.spacing, fill_ml)
    world = _local_to_world(local, p0[0].numpy())
    state = make_state(world, poses=p0, dtype=dtype)
    poses = torch.stack([poses_at((i + 1) * DT) for i in range(steps)]).to(dtype)
    containers = (Container("cup", 0, "cup", CUP_RADIUS, WALL, CUP_HEIGHT),
                  Container("bowl", 1, "bowl", BOWL_RADIUS, WALL))
    return PourScene(model, state, poses, containers, OBJECT_NAMES, traj)


def _local_to_world(p: np.ndarray, pose: np.ndarray) -> np.ndarray:
    rot = quat_to_matrix(torch.as_tensor(pose[3:], dtype=torch.float64)).numpy()
    return p @ rot.T + pose[:3]
