"""Taichi implementation of one Position Based Fluids step (Macklin & Mueller 2013).

Imported only through :mod:`bench.peers.taichi_pbf`, which turns a missing
``taichi`` into :class:`bench.peers.PeerNotInstalled`.  Written for this repo
from the paper's algorithm (checked against a brute-force float64 NumPy
version of the same equations):

  per step
    1. predict      v += dt*g;  p = x + dt*v                (clamped to the box)
    2. neighbours   counting sort of particles into a uniform grid of cell
                    size h (linear cell index over the box = collision-free
                    hash), then one neighbour list per particle from the 27
                    surrounding cells, kept for the whole step
    3. K=3 times    rho_i    = sum_j m W_poly6(p_i - p_j) + rho0 phi_wall(p_i)
                    C_i      = max(rho_i / rho0 - 1, 0)
                    lambda_i = -C_i / (sum_k |grad_k C_i|^2 + eps)
                    dp_i     = m/rho0 sum_j (lambda_i + lambda_j + s_corr) grad W_spiky
                               + lambda_i grad phi_wall
                    p_i     += dp_i                               (clamped to the box)
    4. velocity     v = (p - x) / dt, XSPH viscosity, x = p

Two choices beyond the paper's text, both needed for a dam break that settles
instead of exploding:
  * the constraint is one-sided (only compression is corrected), as in
    SPlisHSPlasH's PBF; the two-sided form pulls the free surface inwards;
  * the box faces count as rest fluid behind the wall (phi_wall, an exact
    half-space integral of poly6).  With clamping alone, particles pile up in
    the wall planes and along the box edges until they shoot out.
eps and the s_corr strength are scaled by D0 (see rest_lattice) so they are
dimensionless.  Everything is float32 on ``ti.cpu``; physical constants are
plain Python attributes of the data-oriented class, so Taichi bakes them into
the kernels as compile-time constants.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np

with contextlib.redirect_stdout(sys.stderr):  # taichi prints a banner on import
    import taichi as ti

TAICHI_VERSION = ".".join(str(v) for v in ti.__version__)


# --------------------------------------------------------------------------- scene


@dataclass
class Params:
    # kernel support radius [m].  With dt fixed at 1/60 the dam break's peak
    # CFL number, sqrt(2 g H) dt / h, grows with the column height H; h = 0.5
    # keeps it under ~0.4 up to 32k particles (h = 0.1 reaches ~0.9 and the
    # wall impact sprays particles at 4x the free-fall speed).
    h: float = 0.5
    spacing_ratio: float = 0.5  # rest spacing / h  -> ~33 neighbours at rest density
    rho0: float = 1000.0  # rest density [kg/m^3]
    dt: float = 1.0 / 60.0
    iterations: int = 3
    eps: float = 0.05  # relaxation (CFM) in lambda's denominator, relative to D0 (see rest_lattice)
    # artificial pressure s_corr (tensile instability): the paper's k, n, dq; k is in units of 1/D0
    scorr_k: float = 0.1
    scorr_n: int = 4
    scorr_dq: float = 0.2  # delta q as a fraction of h
    unilateral: bool = True  # C = max(rho/rho0 - 1, 0), as SPlisHSPlasH's PBF does
    xsph_c: float = 0.01  # XSPH viscosity; 0 disables
    gravity: tuple = (0.0, -9.81, 0.0)
    max_neighbors: int = 96
    seed: int = 0
    aspect: float = 2.0  # column height / width
    box_length: float = 3.0  # box length along x in column widths


@dataclass
class Scene:
    positions: np.ndarray  # (N, 3) float32
    box_lo: np.ndarray  # (3,)
    box_hi: np.ndarray  # (3,)
    mass: float
    grad_sq_rest: float  # D0, see rest_lattice()
    block: tuple = field(default=(0, 0, 0))  # columns in x, layers in y, columns in z


def rest_lattice(params: Params) -> tuple[float, float]:
    """(mass, D0) for a perfect interior lattice at the rest spacing.

    mass makes that lattice sit exactly at rest density.  D0 is the lattice's
    sum_k |grad_k C_i|^2, the natural scale of lambda's denominator: eps and
    the s_corr strength k are given relative to it, so both stay dimensionless
    and mean the same at any h, rho0 or spacing.
    """
    h = params.h
    s = params.spacing_ratio * h
    reach = int(math.ceil(h / s)) + 1
    ax = np.arange(-reach, reach + 1, dtype=np.float64) * s
    r = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), axis=-1).reshape(-1, 3)
    d = np.linalg.norm(r, axis=1)
    inside = d < h
    w = 315.0 / (64.0 * math.pi * h**9) * (h * h - d[inside] ** 2) ** 3
    mass = float(params.rho0 / w.sum())
    nz = inside & (d > 0)
    grad = (-45.0 / (math.pi * h**6) * (h - d[nz]) ** 2 / d[nz])[:, None] * r[nz]
    grad *= mass / params.rho0
    d0 = float((grad**2).sum() + (grad.sum(axis=0) ** 2).sum())
    return mass, d0


def make_dam_break(n_particles: int, params: Params) -> Scene:
    """A column of exactly N particles on a lattice of spacing spacing_ratio*h
    (jittered by 1%), ``aspect`` times as tall as wide (the top layer may be
    partial), at one end of a box ``box_length`` columns long and as wide (z)
    as the column.  Particles are numbered x fastest, then z, then y."""
    n = int(n_particles)
    if n < 8:
        raise ValueError("need at least 8 particles")
    s = params.spacing_ratio * params.h
    nb = max(2, int(round((n / params.aspect) ** (1.0 / 3.0))))  # columns along x and z
    layers = int(math.ceil(n / (nb * nb)))
    idx = np.arange(n)
    ix, iz, iy = idx % nb, (idx // nb) % nb, idx // (nb * nb)
    rng = np.random.default_rng(params.seed)
    pos = (np.stack([ix, iy, iz], axis=1) + 0.5) * s
    pos += rng.uniform(-0.01 * s, 0.01 * s, size=pos.shape)  # break lattice symmetry
    width, height = nb * s, layers * s
    box_lo = np.zeros(3)
    top = max(1.5 * height, height + 2.0 * params.h)
    box_hi = np.array([params.box_length * width, top, width])
    mass, d0 = rest_lattice(params)
    return Scene(pos.astype(np.float32), box_lo, box_hi, mass, d0, (nb, layers, nb))


# --------------------------------------------------------------------------- solver


@ti.data_oriented
class TaichiPBF:
    def __init__(self, scene: Scene, params: Params):
        self.params = params
        n = scene.positions.shape[0]
        self.n = n
        h = params.h
        # compile-time constants
        self.h = h
        self.h2 = h * h
        self.inv_h = 1.0 / h
        self.dt = params.dt
        self.inv_dt = 1.0 / params.dt
        self.iterations = params.iterations
        self.rho0 = params.rho0
        self.mass = scene.mass
        self.grad_scale = scene.mass / params.rho0  # grad C_i = m/rho0 * grad W
        self.rest_volume = scene.mass / params.rho0
        self.eps = params.eps * scene.grad_sq_rest
        self.poly6_c = 315.0 / (64.0 * math.pi * h**9)
        self.spiky_c = -45.0 / (math.pi * h**6)
        dq = params.scorr_dq * h
        self.inv_w_dq = 1.0 / (self.poly6_c * (h * h - dq * dq) ** 3)
        self.scorr_k = params.scorr_k / scene.grad_sq_rest  # s_corr is added to lambda: same units
        self.scorr_n = params.scorr_n
        self.xsph_c = params.xsph_c
        self.unilateral = bool(params.unilateral)
        self.gravity = [float(g) for g in params.gravity]
        self.max_nbr = params.max_neighbors
        wall = 1e-4 * h  # keep clamped particles a hair inside the walls
        self.lo_in = [float(v) + wall for v in scene.box_lo]
        self.hi_in = [float(v) - wall for v in scene.box_hi]
        self.box_lo = [float(v) for v in scene.box_lo]
        self.box_hi = [float(v) for v in scene.box_hi]
        self.grid = [max(1, int(math.ceil((hi - lo) / h)))
                     for lo, hi in zip(scene.box_lo, scene.box_hi)]
        self.ncells = self.grid[0] * self.grid[1] * self.grid[2]

        vec3 = ti.types.vector(3, ti.f32)
        self.x = ti.field(vec3, shape=n)
        self.p = ti.field(vec3, shape=n)
        self.v = ti.field(vec3, shape=n)
        self.dp = ti.field(vec3, shape=n)
        self.lam = ti.field(ti.f32, shape=n)
        self.density = ti.field(ti.f32, shape=n)
        self.num_nbr = ti.field(ti.i32, shape=n)
        self.nbr = ti.field(ti.i32, shape=(n, self.max_nbr))
        self.cell_of = ti.field(ti.i32, shape=n)
        self.sorted_idx = ti.field(ti.i32, shape=n)
        self.p_sorted = ti.field(vec3, shape=n)
        self.cell_count = ti.field(ti.i32, shape=self.ncells)
        self.cell_start = ti.field(ti.i32, shape=self.ncells + 1)
        self.overflow = ti.field(ti.i32, shape=())

        self.x.from_numpy(scene.positions)
        self.p.from_numpy(scene.positions)
        self.v.fill(0.0)
        self.overflow[None] = 0

    # ---------------------------------------------------------------- helpers
    @ti.func
    def clamp_box(self, q):
        return ti.min(ti.max(q, ti.Vector(self.lo_in)), ti.Vector(self.hi_in))

    @ti.func
    def cell_coord(self, q):
        c = ti.cast(ti.floor((q - ti.Vector(self.box_lo)) * self.inv_h), ti.i32)
        return ti.min(ti.max(c, 0), ti.Vector(self.grid) - 1)

    @ti.func
    def cell_index(self, c):
        return c[0] + self.grid[0] * (c[1] + self.grid[1] * c[2])

    @ti.func
    def poly6(self, r2):
        w = 0.0
        if r2 < self.h2:
            d = self.h2 - r2
            w = self.poly6_c * d * d * d
        return w

    @ti.func
    def spiky_grad(self, r):
        g = ti.Vector([0.0, 0.0, 0.0])
        rl = r.norm()
        if rl > 1e-9 and rl < self.h:
            d = self.h - rl
            g = (self.spiky_c * d * d / rl) * r
        return g

    @ti.func
    def wall_term(self, q):
        """Box walls as rest fluid filling the space behind each face.

        For a particle at distance d < h from a face, the poly6 kernel's mass
        beyond the face is phi(d) = 1/2 - 315/256 * a(d/h) with
        a(u) = u - 4u^3/3 + 6u^5/5 - 4u^7/7 + u^9/9 (the half-space integral of
        poly6), so the wall adds rho0 * phi to the density and
        d phi / d d = -315/(256 h) (1 - u^2)^4 along the face's inward normal
        to grad C_i.  Without it particles pile up on the clamped faces (and
        in 1-D along the box's edges) until they shoot out.
        Returns (sum of phi, grad of it w.r.t. q).
        """
        phi = 0.0
        grad = ti.Vector([0.0, 0.0, 0.0])
        for a in ti.static(range(3)):
            for side in ti.static(range(2)):
                d = 0.0
                if ti.static(side == 0):
                    d = q[a] - self.box_lo[a]
                else:
                    d = self.box_hi[a] - q[a]
                if d < self.h:
                    u = ti.max(d, 0.0) * self.inv_h
                    u2 = u * u
                    poly = u * (1.0 + u2 * (-4.0 / 3.0 + u2 * (6.0 / 5.0
                                                              + u2 * (-4.0 / 7.0 + u2 / 9.0))))
                    phi += 0.5 - (315.0 / 256.0) * poly
                    w = 1.0 - u2
                    dphi = -(315.0 / 256.0) * self.inv_h * (w * w) * (w * w)
                    if ti.static(side == 0):
                        grad[a] += dphi
                    else:
                        grad[a] -= dphi
        return phi, grad

    # ---------------------------------------------------------------- kernels
    @ti.kernel
    def predict(self):
        for i in self.x:
            v = self.v[i] + self.dt * ti.Vector(self.gravity)
            self.v[i] = v
            self.p[i] = self.clamp_box(self.x[i] + self.dt * v)

    @ti.kernel
    def bin_particles(self):
        for c in self.cell_count:
            self.cell_count[c] = 0
        for i in self.p:
            c = self.cell_index(self.cell_coord(self.p[i]))
            self.cell_of[i] = c
            ti.atomic_add(self.cell_count[c], 1)
        ti.loop_config(serialize=True)
        for c in range(self.ncells):  # exclusive prefix sum -> cell_start
            self.cell_start[c + 1] = self.cell_start[c] + self.cell_count[c]
        for c in self.cell_count:
            self.cell_count[c] = 0  # reused as the per-cell fill cursor
        for i in self.p:
            c = self.cell_of[i]
            slot = ti.atomic_add(self.cell_count[c], 1)
            self.sorted_idx[self.cell_start[c] + slot] = i
            self.p_sorted[self.cell_start[c] + slot] = self.p[i]

    @ti.kernel
    def find_neighbors(self):
        # Walk particles in cell order (neighbouring threads/iterations share
        # cells), and read candidates from the cell-sorted position copy: the
        # three cells along x of each (y, z) row are one contiguous range.
        for k in range(self.n):
            i = self.sorted_idx[k]
            pi = self.p_sorted[k]
            ci = self.cell_coord(pi)
            x0 = ti.max(ci[0] - 1, 0)
            x1 = ti.min(ci[0] + 1, self.grid[0] - 1)
            n = 0
            for dy, dz in ti.ndrange((-1, 2), (-1, 2)):
                cy = ci[1] + dy
                cz = ci[2] + dz
                if cy >= 0 and cy < self.grid[1] and cz >= 0 and cz < self.grid[2]:
                    row = self.grid[0] * (cy + self.grid[1] * cz)
                    for q in range(self.cell_start[row + x0], self.cell_start[row + x1 + 1]):
                        if q != k and (pi - self.p_sorted[q]).norm_sqr() < self.h2:
                            if n < self.max_nbr:
                                self.nbr[i, n] = self.sorted_idx[q]
                                n += 1
                            else:
                                self.overflow[None] += 1
            self.num_nbr[i] = n

    @ti.kernel
    def solve_lambda(self):
        for i in self.p:
            pi = self.p[i]
            phi_w, grad_i = self.wall_term(pi)
            rho = self.mass * self.poly6(0.0) + self.rho0 * phi_w
            sum_sq = 0.0
            for k in range(self.num_nbr[i]):
                r = pi - self.p[self.nbr[i, k]]
                rho += self.mass * self.poly6(r.norm_sqr())
                g = self.grad_scale * self.spiky_grad(r)
                grad_i += g
                sum_sq += g.dot(g)
            sum_sq += grad_i.dot(grad_i)
            self.density[i] = rho
            c = rho / self.rho0 - 1.0
            if ti.static(self.unilateral):
                c = ti.max(c, 0.0)  # only resist compression: no clumping at the free surface
            self.lam[i] = -c / (sum_sq + self.eps)

    @ti.kernel
    def solve_delta(self):
        for i in self.p:
            pi = self.p[i]
            li = self.lam[i]
            d = ti.Vector([0.0, 0.0, 0.0])
            for k in range(self.num_nbr[i]):
                j = self.nbr[i, k]
                r = pi - self.p[j]
                ratio = self.poly6(r.norm_sqr()) * self.inv_w_dq
                scorr = -self.scorr_k * ratio ** ti.static(self.scorr_n)
                d += (li + self.lam[j] + scorr) * self.spiky_grad(r)
            _, grad_w = self.wall_term(pi)
            self.dp[i] = self.grad_scale * d + li * grad_w

    @ti.kernel
    def apply_delta(self):
        for i in self.p:
            self.p[i] = self.clamp_box(self.p[i] + self.dp[i])

    @ti.kernel
    def finish_step(self):
        for i in self.p:
            self.v[i] = (self.p[i] - self.x[i]) * self.inv_dt
        if ti.static(self.xsph_c > 0.0):
            for i in self.p:
                pi = self.p[i]
                vi = self.v[i]
                acc = ti.Vector([0.0, 0.0, 0.0])
                for k in range(self.num_nbr[i]):
                    j = self.nbr[i, k]
                    acc += (self.v[j] - vi) * self.poly6((pi - self.p[j]).norm_sqr())
                self.dp[i] = vi + (self.xsph_c * self.rest_volume) * acc
            for i in self.p:
                self.v[i] = self.dp[i]
        for i in self.p:
            self.x[i] = self.p[i]

    @ti.kernel
    def measure_density(self):
        """Density at the current positions with the current neighbour lists
        (overwrites lam with each particle's wall fraction)."""
        for i in self.x:
            xi = self.x[i]
            phi_w, _ = self.wall_term(xi)
            self.lam[i] = phi_w  # scratch: > 0 within h of a wall
            rho = self.mass * self.poly6(0.0) + self.rho0 * phi_w
            for k in range(self.num_nbr[i]):
                rho += self.mass * self.poly6((xi - self.x[self.nbr[i, k]]).norm_sqr())
            self.density[i] = rho

    # ---------------------------------------------------------------- driver
    def step(self):
        self.predict()
        self.bin_particles()
        self.find_neighbors()
        for _ in range(self.iterations):
            self.solve_lambda()
            self.solve_delta()
            self.apply_delta()
        self.finish_step()


def init_taichi(threads: int = 2) -> None:
    with contextlib.redirect_stdout(sys.stderr):
        ti.init(arch=ti.cpu, cpu_max_num_threads=int(threads), default_fp=ti.f32, default_ip=ti.i32,
                log_level=ti.WARN, random_seed=0)


def build(n_particles: int, params: Params | None = None, threads: int = 2) -> TaichiPBF:
    params = params or Params()
    init_taichi(threads)
    return TaichiPBF(make_dam_break(n_particles, params), params)


def _busy_cpu_seconds() -> float:
    """CPU seconds all processes on this machine have spent busy (Linux /proc/stat), or nan."""
    try:
        with open("/proc/stat") as fh:
            ticks = [int(v) for v in fh.readline().split()[1:]]
    except (OSError, ValueError):
        return float("nan")
    idle = ticks[3] + (ticks[4] if len(ticks) > 4 else 0)  # idle + iowait
    return (sum(ticks[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def timed_run(n_particles: int, steps: int, warmup: int, threads: int = 2,
              params: Params | None = None) -> dict:
    sim = build(n_particles, params, threads)
    warmup = max(1, int(warmup))  # the first step JIT-compiles every kernel; never time it
    for _ in range(warmup):
        sim.step()
    ti.sync()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    b0 = _busy_cpu_seconds()
    c0 = time.process_time()
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step()
    ti.sync()
    elapsed = time.perf_counter() - t0
    cpu = time.process_time() - c0
    others = (_busy_cpu_seconds() - b0 - cpu) / elapsed if elapsed > 0 else float("nan")
    nn = sim.num_nbr.to_numpy()
    sim.measure_density()
    # bulk: full kernel support from particles alone -- not at the free surface, not by a wall
    bulk = (sim.density.to_numpy() >= 0.95 * sim.rho0) & (sim.lam.to_numpy() == 0.0)
    return {
        "peer": "taichi",
        "version": TAICHI_VERSION,
        "particles": sim.n,
        "steps": int(steps),
        "particle_steps_per_s": sim.n * steps / elapsed if elapsed > 0 else float("nan"),
        "mean_neighbors": float(nn.mean()),  # all particles, self excluded, after the last step
        "iterations": sim.iterations,
        "mean_neighbors_bulk": float(nn[bulk].mean()) if bulk.any() else float("nan"),
        "warmup": warmup,
        "seconds": elapsed,
        "threads": int(threads),
        # process CPU seconds per wall second while timing: ~threads when the
        # machine is otherwise idle, lower when something else holds the cores
        "cpu_per_wall": cpu / elapsed if elapsed > 0 else float("nan"),
        # cores kept busy by other processes meanwhile (Linux): > ~0.2 means the timing is
        # contended and the ratio to our simulator should not be trusted
        "other_cores_busy": max(0.0, others) if math.isfinite(others) else others,
        "loadavg_1m_before": load,
        "xsph": sim.xsph_c,
        "dt": sim.dt,
        "h": sim.h,
        "spacing": sim.params.spacing_ratio * sim.h,
        "neighbor_overflow": int(sim.overflow[None]),
    }


def validate(n_particles: int = 4000, steps: int = 600, threads: int = 2,
             params: Params | None = None) -> dict:
    """Run a dam break to rest and report physical sanity numbers."""
    params = params or Params()
    init_taichi(threads)
    scene = make_dam_break(n_particles, params)
    sim = TaichiPBF(scene, params)
    sim.bin_particles()  # neighbour lists at the initial lattice
    sim.find_neighbors()
    sim.measure_density()
    rho_initial = sim.density.to_numpy()
    nn_initial = sim.num_nbr.to_numpy()
    for _ in range(steps):
        sim.step()
    sim.measure_density()
    x = sim.x.to_numpy()
    v = sim.v.to_numpy()
    rho = sim.density.to_numpy()
    nn = sim.num_nbr.to_numpy()
    h = params.h
    lo, hi = scene.box_lo, scene.box_hi
    finite = bool(np.isfinite(x).all() and np.isfinite(v).all())
    in_box = bool(((x >= lo - 1e-6) & (x <= hi + 1e-6)).all())
    surface = float(np.percentile(x[:, 1], 99.0))
    interior = ((x[:, 0] > lo[0] + h) & (x[:, 0] < hi[0] - h)
                & (x[:, 2] > lo[2] + h) & (x[:, 2] < hi[2] - h)
                & (x[:, 1] > lo[1] + h) & (x[:, 1] < surface - h))
    speed = np.linalg.norm(v, axis=1)

    def interior_initial():
        s = params.spacing_ratio * h
        nb, layers, _ = scene.block
        p0 = scene.positions
        return ((p0[:, 0] > h) & (p0[:, 0] < nb * s - h) & (p0[:, 2] > h) & (p0[:, 2] < nb * s - h)
                & (p0[:, 1] > h) & (p0[:, 1] < (layers - 1) * s - h))

    i0 = interior_initial()

    def mean_or_none(a, sel, scale=1.0):
        return float(a[sel].mean() / scale) if sel.any() else None

    column = scene.block[1] * params.spacing_ratio * h
    return {
        "particles": sim.n,
        "steps": steps,
        "sim_time_s": steps * params.dt,
        "finite": finite,
        "in_box": in_box,
        "initial_interior_density_ratio": mean_or_none(rho_initial, i0, params.rho0),
        "initial_interior_neighbors": mean_or_none(nn_initial, i0),
        "interior_particles": int(interior.sum()),
        "interior_density_ratio": mean_or_none(rho, interior, params.rho0),
        "interior_density_ratio_max":
            float(rho[interior].max() / params.rho0) if interior.any() else None,
        "interior_neighbors": mean_or_none(nn, interior),
        "mean_neighbors": float(nn.mean()),
        "mean_speed": float(speed.mean()),
        "max_speed": float(speed.max()),
        "surface_height": surface,
        "column_height": float(column),
        "free_fall_speed": float(math.sqrt(2.0 * abs(params.gravity[1]) * column)),
        "settled_depth_expected": float(n_particles * (params.spacing_ratio * h) ** 3
                                        / ((hi[0] - lo[0]) * (hi[2] - lo[2]))),
        "neighbor_overflow": int(sim.overflow[None]),
    }
