"""SPNets: Position Based Fluids as differentiable layers (thesis §8.1–8.2, SPEC §1).

``step(model, state, poses) -> state`` is a pure function: :class:`FluidModel` is static
(kernel radius, time step, objects, calibrated constants, extra terms) and holds the
learnable :class:`FluidParams` (tensors that take gradients); :class:`FluidState` holds the
time-varying tensors. The step is built from small phases: predict (gravity and extra
accelerations, anti-clipped moves), neighbours (hash grid, particles kept sorted by cell),
K constraint iterations (pressure, cohesion, surface tension, extra position terms,
anti-clipped collisions), velocity update and viscosity.

Two numerically equivalent back ends compute the particle-pair sums: ``"torch"`` composes
ConvSP calls exactly as the thesis expands them (the reference), ``"fused"`` runs the C++
kernels of :mod:`liquidtwin.sim.fused` (fast path on CPU). ``"auto"`` picks fused when it can.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch.utils.checkpoint import checkpoint

from . import collide, fused, walls
from .collide import PIECE_FRACTION  # noqa: F401  (re-exported: anti-clipping piece / wall)
from .convsp import convsp
from .neighbors import Neighbors, cell_order, check_points, find_neighbors
from .packing import calibrate, particle_volume
from .sdf import POSE_DIM, SDFGrid, check_poses
from .terms import Term

PARAM_NAMES = ("lambda_omega", "lambda_c", "lambda_s", "lambda_v", "rho0")


@dataclass(frozen=True, eq=False)
class FluidParams:
    """Learnable fluid parameters, each a 0-d tensor.

    Attributes:
      lambda_omega: pressure stiffness relative to the calibrated κ (1 = calibrated).
      lambda_c: cohesion; displacement λ_c·h·Σ_j n_ij W_c(d_ij).
      lambda_s: surface tension; displacement (λ_s/ρ̃0)·h·Σ_j (n_j − n_i), ρ̃0 = ρ0·h³.
      lambda_v: viscosity, 1/s; velocity change dt·(λ_v/ρ0)·Σ_j W_ρ(d_ij)(v_j − v_i).
      rho0: rest density in kernel units (Σ_j W_ρ with unit mass), m⁻³.
    """

    lambda_omega: torch.Tensor
    lambda_c: torch.Tensor
    lambda_s: torch.Tensor
    lambda_v: torch.Tensor
    rho0: torch.Tensor

    def __post_init__(self):
        for name in PARAM_NAMES:
            value = getattr(self, name)
            if not isinstance(value, torch.Tensor):
                value = torch.tensor(float(value), dtype=torch.float64)
                object.__setattr__(self, name, value)
            if value.numel() != 1:
                raise ValueError(f"fluid parameter {name} must be a scalar, got shape {tuple(value.shape)}")
            if not bool(torch.isfinite(value.detach()).all()):
                raise ValueError(f"fluid parameter {name} is not finite: {value.detach().item()}")
        if float(self.rho0.detach()) <= 0:
            raise ValueError(f"rest density rho0 must be > 0, got {float(self.rho0.detach())}")

    def replace(self, **changes) -> "FluidParams":
        return dataclasses.replace(self, **changes)

    def to(self, dtype=None, device=None) -> "FluidParams":
        return FluidParams(**{n: getattr(self, n).to(dtype=dtype, device=device) for n in PARAM_NAMES})

    def as_dict(self) -> dict[str, float]:
        return {n: float(getattr(self, n).detach()) for n in PARAM_NAMES}


@dataclass(frozen=True)
class FluidState:
    """Time-varying state, particles sorted by hash-grid cell.

    Attributes:
      x: (N, 3) particle positions, m.
      v: (N, 3) particle velocities, m/s.
      ids: (N,) int64 original particle labels (``x[i]`` is particle ``ids[i]``).
      poses: (M, 7) object poses at time t (tx ty tz qx qy qz qw).
      t: time, s.
    """

    x: torch.Tensor
    v: torch.Tensor
    ids: torch.Tensor
    poses: torch.Tensor
    t: float = 0.0

    def by_id(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(x, v) reordered by increasing particle id (row k is particle k while no particle
        has been removed; see :meth:`subset`) (differentiable)."""
        order = torch.argsort(self.ids)
        return self.x[order], self.v[order]

    def subset(self, keep: torch.Tensor) -> "FluidState":
        """The state without the particles where ``keep`` (N,) bool is False (their ids go)."""
        return FluidState(self.x[keep], self.v[keep], self.ids[keep], self.poses, self.t)


#: Liquid this many rest spacings deep per solver iteration stays at rest (relaxation 4, dt
#: 1/120 s, h 1.1 cm, settled in its container); deeper liquid bounces and boils over, because
#: the pressure solve spreads its correction a few spacings per iteration. Measured: a narrow
#: cup filled 16 spacings deep boils at 4 iterations (mean speed 0.37 m/s, its measured volume
#: 17 % off after 1 s) and rests at 6 (0.004 m/s; tests/server/test_physics.py); in the
#: generator's full scenes (uncommitted diagnostic, the README's "Solver iterations and deep
#: liquid") a bottle 30 deep boils at 6, stirs at 8 (~0.09 m/s), rests at 10 (0.01 m/s), and
#: liquid 11.5 deep rests at 4, 20 deep at 7. Other h, dt or relaxation were not measured.
LAYERS_PER_ITERATION = 3.0

#: Neighbour-list skin of models created without one, in units of h. 0: the lists are rebuilt
#: at every solver iteration and hold only pairs closer than h (the fastest; see
#: ``FluidModel.skin``). Any skin gives the same step up to float rounding, so tests and
#: ``bench/perturbed.py`` set it to draw other realisations of chaotic rollouts.
DEFAULT_SKIN = 0.0


#: Solver iterations per rest spacing a particle moves into the liquid below in one step
#: (speed × dt / spacing) that :func:`iterations_for_impact` gives. Measured by
#: ``bench/impact_splash.py`` (a column falling into a shallow pool, the same liquid solved
#: with 4-16 iterations): at 4 iterations the solver throws 1.9 % of the liquid back out of
#: the cup at 1 m/s (1.4 spacings a step at 120 Hz) and 34 % at 2.5 m/s (3.4 spacings); at the
#: measured counts on either side of this rule's (5, 7, 9, 11 at 1, 1.5, 2, 2.5 m/s) it
#: throws out 0.71-1.90, 0.15-0.85, 0.29-0.66 and 0.90-1.07 %. At 4.1 spacings (3 m/s) no
#: count up to 16 brought it under 3 %. Other h, relaxation or pool depths were not measured.
ITERATIONS_PER_PENETRATION = 3.0


def iterations_for_impact(speed: float, dt: float, spacing: float, least: int = 1) -> int:
    """Fewest solver iterations that take liquid arriving at ``speed`` m/s without throwing
    it back out (:data:`ITERATIONS_PER_PENETRATION` per rest spacing it moves in a step of
    ``dt`` s), and at least ``least``. Too few leave the overlap of an impact half solved,
    and the next step turns it into velocity: splashes leave faster than they came in."""
    if not (math.isfinite(speed) and speed >= 0 and dt > 0 and spacing > 0):
        raise ValueError(f"need speed >= 0, dt > 0, spacing > 0 (got {speed}, {dt}, {spacing})")
    return max(int(least), math.ceil(ITERATIONS_PER_PENETRATION * speed * dt / spacing - 1e-9))


def iterations_for_depth(depth_m: float, spacing: float, least: int = 1) -> int:
    """Fewest solver iterations that hold liquid ``depth_m`` deep at rest
    (:data:`LAYERS_PER_ITERATION`), and at least ``least``."""
    return max(int(least), math.ceil(depth_m / spacing / LAYERS_PER_ITERATION - 1e-9))


@dataclass(frozen=True, eq=False)
class FluidModel:
    """Static description of the fluid and the scene. Build with :meth:`create`.

    Attributes:
      h: kernel radius, m.
      spacing: rest distance between particles, m (default 0.55·h).
      dt: time step, s.
      gravity: (3,) m/s², y up.
      iterations: constraint iterations K.
      objects: rigid objects as SDF grids.
      params: learnable :class:`FluidParams`.
      terms: extra :class:`~liquidtwin.sim.terms.Term` s.
      kappa: calibrated pressure stiffness, m⁶ (ω = λ_ω κ max(ρ − ρ0, 0)).
      rest_density: calibrated ρ0, m⁻³ (the default of ``params.rho0``).
      collision_distance: particles are kept this far outside objects, m.
      relaxation, damp: constraint corrections are divided by max(count/(1 + relaxation), damp).
      max_speed: optional speed cap, m/s, applied before prediction.
      skin: neighbour lists are built to h + skin and rebuilt when a particle moves skin/2.
        The default 0 rebuilds them at every solver iteration: every pair pass then walks
        only pairs closer than h, which saves more than the extra builds cost (with the
        dense-grid search of the same change, steps 1.25–1.45× faster than with 0.1 h:
        ``bench/step_versions.py``).
      max_pieces: upper bound on anti-clipping pieces per move (a warning names any excess).
      backend: "auto", "torch" (ConvSP reference) or "fused" (C++ kernels).
      reference_iterations: None (SPNets as published): cohesion and surface tension move the
        particles by their full λ in every one of the K iterations, so K is part of the
        liquid — more iterations, a stickier liquid (``bench/pour_iterations.py``: a quick
        cup tilted to 86° pours 19.5 ml at K = 4 and nothing at K = 16; 23.9 and 23.3 ml
        with λ_c = 0). An integer K_ref scales each iteration's cohesion and tension by
        K_ref / K, so a step applies what K_ref iterations apply and λ_c, λ_s mean the same
        liquid at any K: K then sets only how well the constraints are solved.
      max_correction: None (SPNets as published), or the longest move, m, the fluid's
        constraints (pressure, cohesion, tension) may give a particle in one solver
        iteration; longer corrections are shortened along their direction. Extra terms'
        moves (the perception tracker's) and the collision push-out are not capped. SPNets' pressure is linear in the excess density, so a small blob that a
        step's prediction squeezes to twice the rest density (a falling drop whose particles
        converge) gets corrections longer than h in one iteration: a particle leaves its
        neighbours at 2 m/s, faster than anything around it. Traced in the pouring task: a
        drop below the cup's lip at 1.77 ρ0 moved one particle 11 mm in one iteration
        (README, "Bursting drops"; tests/server/test_pbf_max_correction.py bursts a squeezed
        blob). Half a rest spacing stops the bursts and shortens little else: over the
        control tasks' 12 ml pour (6.05 mm spacing, every step of the run and of its MPC) an
        iteration's largest correction is a median 1.1 mm, and 1.8 in 10,000 corrections
        exceed the cap (the control tasks' model:
        ``generate.world.CONTROL_MAX_CORRECTION_SPACINGS``). An iteration whose corrections
        all stay under the cap is unchanged bit for bit.
      wall_pairs: True (SPNets as published): particles within h are neighbours whatever lies
        between them. False: pairs whose straight segment passes through an object are cut
        from the step's neighbour lists (:mod:`liquidtwin.sim.walls`), so liquid on the two
        sides of a wall neither pushes nor holds the other. Traced in the pouring task: the
        last drops of a pour hung under the cup's 3 mm base, held by cohesion with 9-11
        particles inside it (README, "Cohesion through walls"). Steps with no pair across a
        wall are unchanged bit for bit.
    """

    h: float
    spacing: float
    dt: float
    gravity: tuple[float, float, float]
    iterations: int
    objects: tuple[SDFGrid, ...]
    params: FluidParams
    terms: tuple[Term, ...]
    kappa: float
    rest_density: float
    collision_distance: float
    relaxation: float
    damp: float
    max_speed: float | None
    skin: float
    max_pieces: int
    backend: str
    reference_iterations: int | None = None
    max_correction: float | None = None
    wall_pairs: bool = True
    _normal_dilation: float = field(default=0.0, repr=False)

    @staticmethod
    def create(h: float = 0.1, *, spacing: float | None = None, dt: float = 1.0 / 60.0,
               gravity=(0.0, -9.8, 0.0), iterations: int = 3, objects=(), params: dict | None = None,
               terms=(), collision_distance: float | None = None, relaxation: float = 3.0,
               damp: float = 1.0, max_speed: float | None = None, skin: float | None = None,
               max_pieces: int = 256, backend: str = "auto",
               reference_iterations: int | None = None, max_correction: float | None = None,
               wall_pairs: bool = True) -> "FluidModel":
        """A model with calibrated rest density and stiffness.

        ``params`` overrides defaults (λ_ω = 1, λ_c = 0.1, λ_s = 0, λ_v = 60 1/s,
        ρ0 = calibrated); values may be floats or tensors (keep ``requires_grad``).
        """
        if not h > 0 or not dt > 0 or iterations < 1:
            raise ValueError(f"need h > 0, dt > 0, iterations >= 1 (got {h}, {dt}, {iterations})")
        if reference_iterations is not None and (isinstance(reference_iterations, bool) or reference_iterations < 1
                                                or int(reference_iterations) != reference_iterations):
            raise ValueError(f"reference_iterations must be None or a whole number >= 1, got {reference_iterations!r}")
        if max_correction is not None and not (isinstance(max_correction, (int, float))
                                               and not isinstance(max_correction, bool)
                                               and math.isfinite(max_correction) and max_correction > 0):
            raise ValueError(f"max_correction must be None or a distance > 0 m, got {max_correction!r}")
        if backend not in ("auto", "torch", "fused"):
            raise ValueError(f"backend must be auto, torch or fused, got {backend!r}")
        if backend == "fused" and not fused.available():
            raise RuntimeError("backend 'fused' needs the liquidtwin._native extension (reinstall the server "
                               "package with a C++ compiler: pip install --no-build-isolation -e server)")
        spacing = 0.55 * h if spacing is None else spacing
        rho0, kappa = calibrate(h, spacing)
        values = dict(lambda_omega=1.0, lambda_c=0.1, lambda_s=0.0, lambda_v=60.0, rho0=rho0)
        unknown = set(params or {}) - set(values)
        if unknown:
            raise ValueError(f"unknown fluid parameters {sorted(unknown)}; expected {PARAM_NAMES}")
        values.update(params or {})
        objects = tuple(objects)
        for o in objects:
            if not isinstance(o, SDFGrid):
                raise TypeError(f"objects must be SDFGrid, got {type(o).__name__}")
        dil = 0.5 * min([o.cell for o in objects], default=h)
        return FluidModel(
            h=float(h), spacing=float(spacing), dt=float(dt), gravity=tuple(float(g) for g in gravity),
            iterations=int(iterations), objects=objects, params=FluidParams(**values), terms=tuple(terms),
            kappa=kappa, rest_density=rho0,
            collision_distance=0.0125 * h if collision_distance is None else float(collision_distance),
            relaxation=float(relaxation), damp=float(damp), max_speed=max_speed,
            skin=DEFAULT_SKIN * h if skin is None else float(skin), max_pieces=int(max_pieces), backend=backend,
            reference_iterations=None if reference_iterations is None else int(reference_iterations),
            max_correction=None if max_correction is None else float(max_correction),
            wall_pairs=bool(wall_pairs), _normal_dilation=dil,
        )

    def replace(self, **changes) -> "FluidModel":
        return dataclasses.replace(self, **changes)

    def with_params(self, **values) -> "FluidModel":
        """Model with some fluid parameters replaced (floats or tensors)."""
        return self.replace(params=self.params.replace(
            **{k: v if isinstance(v, torch.Tensor) else torch.tensor(float(v), dtype=torch.float64)
               for k, v in values.items()}))

    @property
    def particle_volume(self) -> float:
        """Liquid volume per particle at rest, m³ (multiply by 1e6 for ml)."""
        return particle_volume(self.spacing)

    def use_fused(self, x: torch.Tensor) -> bool:
        if self.backend == "torch":
            return False
        return fused.available(x.device)


def make_state(x, v=None, poses=None, *, dtype=torch.float32, device="cpu", t: float = 0.0) -> FluidState:
    """A :class:`FluidState` from arrays: x (N, 3) m, v (N, 3) m/s (default 0), poses (M, 7)."""
    x = torch.as_tensor(x, dtype=dtype, device=device)
    v = torch.zeros_like(x) if v is None else torch.as_tensor(v, dtype=dtype, device=device)
    poses = torch.zeros(0, POSE_DIM, dtype=dtype, device=device) if poses is None else \
        torch.as_tensor(poses, dtype=dtype, device=device)
    check_points(x, "particle positions")
    if x.shape[0] == 0:
        raise ValueError("empty particle set: a fluid state needs at least one particle")
    check_points(v, "particle velocities")
    if v.shape != x.shape:
        raise ValueError(f"velocities {tuple(v.shape)} do not match positions {tuple(x.shape)}")
    ids = torch.arange(x.shape[0], device=x.device)
    return FluidState(x, v, ids, poses.reshape(-1, POSE_DIM), float(t))


# ------------------------------------------------------------------ pair passes (reference)

def density_normals(x: torch.Tensor, nb: Neighbors, h: float):
    """ρ_i = Σ_j W_ρ(d_ij) (N,), neighbour count (N,), n_i = Σ_j n_ij W_c(d_ij) (N, 3).

    n_i is built from one 4-channel ConvSP with the W_c/d kernel: Σ x_j W̄ − x_i Σ W̄.
    """
    ones = torch.ones(x.shape[0], 1, dtype=x.dtype, device=x.device)
    rho = convsp(x, ones[:, 0], "rho", h, neighbors=nb)
    count = convsp(x, ones[:, 0], "constant", h, neighbors=nb).detach()
    s = convsp(x, torch.cat([ones, x], 1), "cohesion", h, neighbors=nb, dis_norm=True)
    nrm = s[:, 1:] - x * s[:, :1]
    return rho, count, nrm


def pressure_tension(x: torch.Tensor, omega: torch.Tensor, nrm: torch.Tensor, count: torch.Tensor,
                     nb: Neighbors, h: float):
    """Pressure sum Σ_j n_ji (ω_i + ω_j) W_ω(d_ij) (N, 3) by the thesis's four-term
    expansion (one 8-channel ConvSP), and tension sum Σ_{d_ij<h} (n_j − n_i) (N, 3)."""
    ones = torch.ones(x.shape[0], 1, dtype=x.dtype, device=x.device)
    w = omega[:, None]
    s = convsp(x, torch.cat([ones, w, x, x * w], 1), "omega", h, neighbors=nb, dis_norm=True)
    pressure = x * w * s[:, 0:1] + x * s[:, 1:2] - w * s[:, 2:5] - s[:, 5:8]
    tension = convsp(x, nrm, "constant", h, neighbors=nb) - nrm * count[:, None]
    return pressure, tension


def viscosity_sum(x: torch.Tensor, v: torch.Tensor, rho: torch.Tensor, nb: Neighbors, h: float):
    """Σ_j W_ρ(d_ij)(v_j − v_i) (N, 3) = ConvSP(V) − V·ρ."""
    return convsp(x, v, "rho", h, neighbors=nb) - v * rho[:, None]


# ------------------------------------------------------------------ step phases

class _Lists:
    """Neighbour lists of the sorted particles, plus where they were built (for the skin test)."""

    def __init__(self, model: FluidModel, x: torch.Tensor, poses: torch.Tensor | None = None):
        self.model = model
        self.radius = model.h + model.skin
        self.fused = model.use_fused(x)
        self.rebuilds = 0
        # wall_pairs False: every list drops the pairs a wall separates (objects at the
        # step's end poses, where the solver iterations hold them)
        self.cut_poses = None if model.wall_pairs or not model.objects else poses
        self.order = self._build(x)

    def _build(self, x: torch.Tensor) -> torch.Tensor:
        if self.fused:
            order, self.row_ptr, self.col = fused.sorted_neighbors(x, self.radius)
            order = order.to(x.device)
        else:
            order = cell_order(x, self.radius)
            nb = find_neighbors(x.detach()[order], None, self.radius)
            self.row_ptr, self.col = nb.row_ptr, nb.col
        if self.cut_poses is not None:
            self.row_ptr, self.col = walls.cut_pairs(x.detach()[order], self.row_ptr, self.col, self.model.objects,
                                                     self.cut_poses, self.radius, native=self.fused)
        if self.model.skin > 0:     # where the skin test measures moves from
            self.anchor = x.detach()[order]
        return order

    @property
    def nb(self) -> Neighbors:
        return Neighbors(self.row_ptr, self.col, self.radius)

    def refresh(self, x: torch.Tensor) -> torch.Tensor | None:
        """Rebuild when some particle moved more than skin/2; returns the new order or None.
        With no skin the lists are rebuilt without looking (a rebuild after no move gives
        the same lists)."""
        if self.model.skin > 0:
            moved = (x.detach() - self.anchor).norm(dim=-1).max()
            if float(moved) * 2.0 <= self.model.skin:
                return None
        self.rebuilds += 1
        return self._build(x)

    def density_normals(self, x):
        if self.fused:
            return fused.density_normals(x, self.row_ptr, self.col, self.model.h)
        return density_normals(x, self.nb, self.model.h)

    def pressure_tension(self, x, omega, nrm, count):
        if self.fused:
            return fused.pressure_tension(x, omega, nrm, self.row_ptr, self.col, self.model.h)
        return pressure_tension(x, omega, nrm, count, self.nb, self.model.h)

    def viscosity(self, x, v, rho):
        if self.fused:
            return fused.viscosity(x, v, self.row_ptr, self.col, self.model.h)
        return viscosity_sum(x, v, rho, self.nb, self.model.h)


def collide_move(model: FluidModel, x: torch.Tensor, delta: torch.Tensor, pose_a: torch.Tensor,
                 pose_b: torch.Tensor) -> torch.Tensor:
    """Move particles x (N, 3) m by ``delta`` (N, 3) m while objects move from ``pose_a`` to
    ``pose_b`` (M, 7), without letting any particle pass through a wall (anti-clipping).

    The move is split into pieces, each shorter than a third of the wall of every object the
    particle can reach once the objects' sweeps are added; after each piece particles are
    pushed out of objects posed at the matching fraction of their motion. Only particles that
    could reach an object during the move (by a lower bound on their distance) take part,
    and only for the objects they can reach (:mod:`liquidtwin.sim.collide`). Differentiable
    w.r.t. x, delta and the poses; when the C++ extension is built (backend auto/fused, CPU)
    the pieces run natively with the same result, and so does their backward pass.
    Returns (N, 3) positions, m.
    """
    if not model.objects:
        return x + delta
    same = pose_a is pose_b
    pose_a = pose_a.to(x)
    pose_b = pose_a if same else pose_b.to(x)
    native = model.use_fused(x) and x.dtype in (torch.float32, torch.float64)
    plan = collide.plan_collisions(model.objects, x, delta, pose_a, pose_b, model.collision_distance,
                                   model.max_pieces, native)
    if plan is None:
        return x + delta
    grad = torch.is_grad_enabled() and any(t.requires_grad for t in (x, delta, pose_a, pose_b))
    move = (collide.move_native_grad if grad else collide.move_native) if native else collide.move_torch
    return move(model.objects, x, delta, pose_a, pose_b, plan, model.collision_distance, model._normal_dilation)


def _check_step_inputs(model: FluidModel, state: FluidState, poses: torch.Tensor) -> None:
    if state.x.shape[0] == 0:
        raise ValueError("empty particle set: nothing to simulate")
    check_points(state.x, "particle positions")
    check_points(state.v, "particle velocities")
    check_poses(poses, len(model.objects))
    check_poses(state.poses, len(model.objects))


def step(model: FluidModel, state: FluidState, poses: torch.Tensor | None = None) -> FluidState:
    """Advance the fluid by one time step dt (SPEC §1, thesis Fig. 8.1).

    Args:
      model: static :class:`FluidModel` (with learnable params).
      state: :class:`FluidState` at time t.
      poses: (M, 7) object poses at t + dt; objects move linearly from ``state.poses``
        during the step. ``None`` keeps them where they are.
    Returns:
      the state at t + dt, particles re-sorted by cell.
    """
    poses = state.poses if poses is None else poses.to(state.x)
    _check_step_inputs(model, state, poses)
    p = model.params
    x0, v = state.x, state.v
    dt, h = model.dt, model.h

    # Predict: gravity and extra accelerations, optional speed cap, anti-clipped move.
    acc = torch.tensor(model.gravity, dtype=x0.dtype, device=x0.device).expand_as(v)
    for term in model.terms:
        a = term.acceleration(model, state)
        if a is not None:
            acc = acc + a
    v = v + dt * acc
    if model.max_speed is not None:
        speed = v.norm(dim=-1, keepdim=True)
        v = v * torch.clamp(model.max_speed / speed.clamp_min(1e-12), max=1.0)
    x = collide_move(model, x0, dt * v, state.poses, poses)

    # Neighbours; keep everything sorted by cell from here on.
    lists = _Lists(model, x, poses)
    order, ids = lists.order, state.ids
    x, x0, ids = x[order], x0[order], ids[order]

    rho0 = p.rho0.to(x)
    stiff = p.lambda_omega.to(x) * model.kappa
    per = 1.0 if model.reference_iterations is None else model.reference_iterations / model.iterations
    coh = p.lambda_c.to(x) * (h * per)
    tens = p.lambda_s.to(x) * (h * per) / (rho0 * h**3)
    for it in range(model.iterations):
        # The first iteration's positions are the ones just listed (now sorted): a rebuild
        # would return the identity order and the same lists (the cell sort is stable).
        order = lists.refresh(x) if it > 0 else None
        if order is not None:
            x, x0, ids = x[order], x0[order], ids[order]
        rho, count, nrm = lists.density_normals(x)
        omega = stiff * F.relu(rho - rho0)
        pressure, tension = lists.pressure_tension(x, omega, nrm, count)
        scale = torch.clamp(count / (1.0 + model.relaxation), min=model.damp)[:, None]
        delta = (pressure + coh * nrm + tens * tension) / scale
        if model.max_correction is not None:
            delta = delta * torch.clamp(model.max_correction / delta.norm(dim=1, keepdim=True).clamp_min(1e-12), max=1.0)
        for term in model.terms:
            d = term.position_delta(model, x, ids)
            if d is not None:
                delta = delta + d
        x = collide_move(model, x, delta, poses, poses)

    v = (x - x0) / dt
    order = lists.refresh(x)
    if order is not None:
        x, v, ids = x[order], v[order], ids[order]
    if lists.fused:
        visc = lists.viscosity(x, v, None)
    else:
        rho = convsp(x, torch.ones_like(x[:, 0]), "rho", h, neighbors=lists.nb)
        visc = lists.viscosity(x, v, rho)
    v = v + dt * p.lambda_v.to(x) / rho0 * visc
    for term in model.terms:
        dv = term.velocity_delta(model, x, v, ids)
        if dv is not None:
            v = v + dv

    if not bool(torch.isfinite(x.detach()).all() and torch.isfinite(v.detach()).all()):
        raise FloatingPointError(f"the step produced non-finite particles at t = {state.t + dt:.4f} s "
                                 f"(parameters {p.as_dict()}); the state before it is unchanged")
    return FluidState(x, v, ids, poses, state.t + dt)


def rollout(model: FluidModel, state: FluidState, poses: torch.Tensor | None = None, steps: int | None = None,
            *, checkpoint_steps: bool = False, keep: bool = True, callback=None):
    """Run many steps.

    Args:
      poses: (T, M, 7) object poses at the end of each step, or None (objects stay).
      steps: number of steps (default T).
      checkpoint_steps: recompute each step in backward instead of storing its
        intermediates (gradient checkpointing; memory O(T·N) instead of O(T·pairs)).
      keep: return every state (else only the last, and the list is empty).
      callback: called with (i, state) after each step (e.g. a progress bar).
    Returns:
      (final state, list of states after each step).
    """
    if poses is None and steps is None:
        raise ValueError("give object poses (T, M, 7) or a number of steps")
    steps = poses.shape[0] if steps is None else steps
    states = []
    for i in range(steps):
        pose = None if poses is None else poses[i]
        if checkpoint_steps and torch.is_grad_enabled():
            state = _checkpointed_step(model, state, pose)
        else:
            state = step(model, state, pose)
        if keep:
            states.append(state)
        if callback is not None:
            callback(i, state)
    return state, states


def _checkpointed_step(model: FluidModel, state: FluidState, pose) -> FluidState:
    def run(x, v, poses_a, poses_b):
        s = step(model, FluidState(x, v, state.ids, poses_a, state.t), poses_b)
        return s.x, s.v, s.ids
    pose = state.poses if pose is None else pose
    x, v, ids = checkpoint(run, state.x, state.v, state.poses, pose, use_reentrant=False)
    return FluidState(x, v, ids, pose, state.t + model.dt)
