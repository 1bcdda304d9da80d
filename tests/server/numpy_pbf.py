"""A slow, independent NumPy Position Based Fluids step: the second implementation the torch
step (liquidtwin.sim.pbf.step) is tested against.

Pure NumPy, float64, no torch and no liquidtwin imports. Everything is written from the
equations (SPEC §1) rather than from the torch code: neighbours are all pairs (O(N²)), the
signed distance grids are interpolated by an explicit trilinear formula, rotations come from
a hand-written quaternion → matrix conversion.

Conventions shared with liquidtwin (they are the definition of the step, not its code):
- kernels, zero for d >= h, self pairs excluded, distances clamped below at 1e-12 m:
  W_rho = 15/(π h³)(1 − d/h)², W_omega = 30/(π h⁴)(1 − d/h),
  W_c = a x³ + b x² − 1 with x = d/h, b = (d0² + d0 + 1)/d0², a = 1 − b, d0 = 0.5;
- poses are (tx, ty, tz, qx, qy, qz, qw), the quaternion normalised before use;
- an SDF grid holds values[i, j, k] at origin + (i, j, k)·cell in the object frame; outside
  its box the value is the one at the nearest box point plus the distance to the box;
- anti-clipping: each particle's move is split into S_i pieces of at most a third of the
  thinnest wall (its own displacement + object sweep), each followed by a push-out against
  the objects posed at the matching fraction of their motion (lerp + nlerp); only particles
  whose SDF lower bound says they could reach an object take part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MIN_DIST = 1e-12
PIECE_FRACTION = 1.0 / 3.0
COHESION_D0 = 0.5


@dataclass
class Grid:
    """An object's signed distance grid (object frame), all in m."""

    values: np.ndarray  # (nx, ny, nz)
    origin: np.ndarray  # (3,)
    cell: float
    thickness: float
    radius: float | None = None  # bounding radius; None: computed from the grid box

    def __post_init__(self):
        self.values = np.asarray(self.values, dtype=np.float64)
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        self.cell = float(self.cell)
        self.thickness = float(self.thickness)

    @property
    def upper(self) -> np.ndarray:
        return self.origin + (np.array(self.values.shape, dtype=np.float64) - 1.0) * self.cell

    @property
    def bounding_radius(self) -> float:
        """Largest distance from the object origin to one of the 8 corners of the grid box."""
        if self.radius is not None:
            return float(self.radius)
        lo, hi = self.origin, self.upper
        best = 0.0
        for cx in (lo[0], hi[0]):
            for cy in (lo[1], hi[1]):
                for cz in (lo[2], hi[2]):
                    best = max(best, math.sqrt(cx * cx + cy * cy + cz * cz))
        return best

    def trilinear(self, p: np.ndarray):
        """(value at the point clamped into the grid box, distance from p to the box) for
        object-frame points p (N, 3)."""
        ext = np.array(self.values.shape) - 1
        u = (p - self.origin) / self.cell
        uc = np.clip(u, 0.0, ext.astype(np.float64))
        outside = np.sqrt((((u - uc) * self.cell) ** 2).sum(-1))
        i0 = np.minimum(np.floor(uc).astype(np.int64), ext - 1)
        f = uc - i0
        val = np.zeros(p.shape[0])
        for di in (0, 1):
            wx = f[:, 0] if di else 1.0 - f[:, 0]
            for dj in (0, 1):
                wy = f[:, 1] if dj else 1.0 - f[:, 1]
                for dk in (0, 1):
                    wz = f[:, 2] if dk else 1.0 - f[:, 2]
                    val += wx * wy * wz * self.values[i0[:, 0] + di, i0[:, 1] + dj, i0[:, 2] + dk]
        return val, outside

    def sdf(self, p: np.ndarray) -> np.ndarray:
        val, outside = self.trilinear(p)
        return val + outside

    def lower_bound(self, p: np.ndarray) -> np.ndarray:
        """Never above the true distance: the grid box contains the object and SDFs are
        1-Lipschitz, so both the distance to the box and (value at box) − (distance) bound it."""
        val, outside = self.trilinear(p)
        return np.maximum(outside, val - outside)


@dataclass
class Params:
    """Everything the step needs, as plain numbers."""

    h: float
    dt: float
    gravity: tuple
    iterations: int
    kappa: float
    collision_distance: float
    relaxation: float
    damp: float
    lambda_omega: float
    lambda_c: float
    lambda_s: float
    lambda_v: float
    rho0: float
    max_pieces: int = 256
    reference_iterations: int | None = None   # cohesion and tension × this / iterations per iteration


# ------------------------------------------------------------------ rotations and poses

def quat_matrix(q) -> np.ndarray:
    """Rotation matrix of the quaternion (x, y, z, w) (normalised here).

    R v = v + 2w (u × v) + 2 u × (u × v) with u = (x, y, z), written out entry by entry.
    """
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q / math.sqrt(float(q @ q))
    return np.array([
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ])


def to_local(p: np.ndarray, pose) -> np.ndarray:
    """World points (N, 3) → object frame: R^T (p − t)."""
    pose = np.asarray(pose, dtype=np.float64)
    R = quat_matrix(pose[3:])
    return np.einsum("ji,nj->ni", R, p - pose[:3])


def _unit(q):
    q = np.asarray(q, dtype=np.float64)
    return q / math.sqrt(float(q @ q))


def lerp_pose(pa, pb, s: float) -> np.ndarray:
    """Pose a fraction s of the way: translation lerp, quaternion nlerp on the short arc."""
    pa, pb = np.asarray(pa, dtype=np.float64), np.asarray(pb, dtype=np.float64)
    qa, qb = _unit(pa[3:]), _unit(pb[3:])
    if float(qa @ qb) < 0.0:
        qb = -qb
    q = qa + (qb - qa) * s
    t = pa[:3] + (pb[:3] - pa[:3]) * s
    return np.concatenate([t, _unit(q)])


def sweep(objects, poses_a, poses_b) -> float:
    """Upper bound on how far any point of any object moves: |Δt| + R·θ."""
    best = 0.0
    for o, pa, pb in zip(objects, poses_a, poses_b):
        qa, qb = _unit(pa[3:7]), _unit(pb[3:7])
        c = min(abs(float(qa @ qb)), 1.0)
        theta = 2.0 * math.acos(c)
        move = math.sqrt(float(((np.asarray(pb[:3]) - np.asarray(pa[:3])) ** 2).sum()))
        best = max(best, move + o.bounding_radius * theta)
    return best


# ------------------------------------------------------------------ collisions

def min_sdf(p: np.ndarray, objects, poses) -> np.ndarray:
    vals = [o.sdf(to_local(p, pose)) for o, pose in zip(objects, poses)]
    return np.min(np.stack(vals, 0), 0)


def push_out(p: np.ndarray, objects, poses, collision_distance: float, dilation: float,
             stats: dict | None = None) -> np.ndarray:
    """p + max(c − SDF(p), 0)·n̂, n̂ the normalised central-difference gradient of the SDF."""
    centre = min_sdf(p, objects, poses)
    grad = np.zeros_like(p)
    for k in range(3):
        e = np.zeros(3)
        e[k] = dilation
        grad[:, k] = min_sdf(p + e, objects, poses) - min_sdf(p - e, objects, poses)
    norm = np.sqrt((grad * grad).sum(-1))
    normal = grad / np.maximum(norm, 1e-12)[:, None]
    depth = np.maximum(collision_distance - centre, 0.0)
    if stats is not None:
        stats["pushes"] = stats.get("pushes", 0) + int((depth > 0).sum())
        stats["max_depth"] = max(stats.get("max_depth", 0.0), float(depth.max(initial=0.0)))
    return p + depth[:, None] * normal


def collide_move(prm: Params, objects, x, delta, poses_a, poses_b, stats: dict | None = None):
    """Move by delta while the objects go from poses_a to poses_b, never through a wall."""
    if not objects:
        return x + delta
    sw = sweep(objects, poses_a, poses_b)
    reach = np.sqrt((delta * delta).sum(-1))
    bounds = [o.lower_bound(to_local(x, pose)) for o, pose in zip(objects, poses_a)]
    start = np.min(np.stack(bounds, 0), 0)
    margin = prm.collision_distance + 2.0 * max(o.cell for o in objects)
    active = np.nonzero(start < reach + sw + margin)[0]
    out = x + delta
    if active.size == 0:
        return out
    piece = PIECE_FRACTION * min(o.thickness for o in objects)
    counts = [min(max(1, math.ceil((float(r) + sw) / piece)), prm.max_pieces) for r in reach[active]]
    counts = np.array(counts, dtype=np.int64)
    if stats is not None:
        stats["max_pieces"] = max(stats.get("max_pieces", 0), int(counts.max()))
        stats["piece_counts"] = stats.get("piece_counts", set()) | set(counts.tolist())
        stats["active"] = stats.get("active", 0) + int(active.size)
    dilation = 0.5 * min(o.cell for o in objects)
    for pieces in np.unique(counts):  # the particles split into the same number of pieces
        rows = active[counts == pieces]
        xa, da = x[rows], delta[rows] / pieces
        for s in range(1, pieces + 1):
            if s == pieces:
                poses = [np.asarray(p, dtype=np.float64) for p in poses_b]
            else:
                poses = [lerp_pose(pa, pb, s / pieces) for pa, pb in zip(poses_a, poses_b)]
            xa = push_out(xa + da, objects, poses, prm.collision_distance, dilation, stats)
        out[rows] = xa
    return out


# ------------------------------------------------------------------ particle pairs

def pair_tables(x: np.ndarray, h: float):
    """All ordered pairs (i, j), i ≠ j: r_ij = x_i − x_j (N, N, 3), d_ij (N, N), mask d < h."""
    r = x[:, None, :] - x[None, :, :]
    d = np.sqrt(np.maximum((r * r).sum(-1), MIN_DIST**2))
    mask = d < h
    np.fill_diagonal(mask, False)
    return r, d, mask


def w_rho(d, mask, h):
    return np.where(mask, 15.0 / (math.pi * h**3) * (1.0 - d / h) ** 2, 0.0)


def w_omega(d, mask, h):
    return np.where(mask, 30.0 / (math.pi * h**4) * (1.0 - d / h), 0.0)


def w_cohesion(d, mask, h):
    d0 = COHESION_D0
    b = (d0 * d0 + d0 + 1.0) / (d0 * d0)
    a = 1.0 - b
    q = d / h
    return np.where(mask, a * q**3 + b * q**2 - 1.0, 0.0)


def constraint_delta(prm: Params, x: np.ndarray) -> np.ndarray:
    """Pressure + cohesion + surface tension displacement of one solver iteration (N, 3)."""
    h = prm.h
    r, d, mask = pair_tables(x, h)
    unit = r / d[..., None]  # n_ji: from j to i
    rho = w_rho(d, mask, h).sum(1)
    count = mask.sum(1).astype(np.float64)
    nrm = -(unit * w_cohesion(d, mask, h)[..., None]).sum(1)  # Σ_j n_ij W_c
    omega = prm.lambda_omega * prm.kappa * np.maximum(rho - prm.rho0, 0.0)
    pressure = (unit * ((omega[:, None] + omega[None, :]) * w_omega(d, mask, h))[..., None]).sum(1)
    tension = (mask[..., None] * (nrm[None, :, :] - nrm[:, None, :])).sum(1)
    scale = np.maximum(count / (1.0 + prm.relaxation), prm.damp)
    share = 1.0 if prm.reference_iterations is None else prm.reference_iterations / prm.iterations
    tens = share * prm.lambda_s * h / (prm.rho0 * h**3)
    return (pressure + share * prm.lambda_c * h * nrm + tens * tension) / scale[:, None]


def viscosity(prm: Params, x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Velocity change dt·(λ_v/ρ0)·Σ_j W_rho(d_ij)(v_j − v_i) (N, 3)."""
    _, d, mask = pair_tables(x, prm.h)
    w = w_rho(d, mask, prm.h)
    s = (w[..., None] * (v[None, :, :] - v[:, None, :])).sum(1)
    return prm.dt * prm.lambda_v / prm.rho0 * s


# ------------------------------------------------------------------ the step

def step(prm: Params, objects, x, v, poses_a, poses_b, stats: dict | None = None):
    """One PBF step; particles keep their order. Returns (x, v) at t + dt."""
    x0 = np.asarray(x, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64) + prm.dt * np.asarray(prm.gravity, dtype=np.float64)
    poses_a = np.asarray(poses_a, dtype=np.float64).reshape(-1, 7)
    poses_b = np.asarray(poses_b, dtype=np.float64).reshape(-1, 7)
    x = collide_move(prm, objects, x0, prm.dt * v, poses_a, poses_b, stats)
    for _ in range(prm.iterations):
        x = collide_move(prm, objects, x, constraint_delta(prm, x), poses_b, poses_b, stats)
    v = (x - x0) / prm.dt
    v = v + viscosity(prm, x, v)
    return x, v
