"""Fluid parameters by gradient descent through SPNets (thesis §8.3.1, SPEC §7).

Each iteration samples ``batch`` true states of a :class:`~.data.Sequence`, rolls the model
``horizon`` steps from each with the current parameters (the objects follow their true
poses), sums the loss against the true states at every step of the horizon, and takes one
Adam step. Parameters are optimised in units of their usual size (:data:`SCALES`): a
learning rate of 1e-2 moves λ_c by ~0.001 and λ_v by ~0.6 1/s per iteration; they are kept
≥ 0. The thesis's rate is a constant 1e-2; here it starts at 2e-2 and anneals (cosine) to
1e-3 by the last iteration: faster out of a poor start, and a quiet end (at a constant 1e-2
the projection fit of λ_c 0.15, λ_v 30 descended at ~0.2 1/s per iteration and then wandered
±2 around 27, 9 % off; annealed it ends at 29.8).

A batch whose gradient is far larger than usual (a splash or a thin-wall collision that the
model reproduces only chaotically, even at the true parameters) would kick a converged fit
away: gradients are clipped to :data:`CLIP` × the running mean of the (clipped) gradient
norms (after :data:`WARMUP` iterations). Measured on the ladle at λ_c 0.05, λ_v 60: without
clipping a fit within 0.5 % at iteration 100–260 was kicked to 13 % off by iteration 280.

The estimate is the mean of the last :data:`TAIL` of the iterates (Polyak averaging, which
removes Adam's last-step jitter) and its uncertainty their standard deviation — the
optimiser's spread at convergence, not a posterior width.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm.auto import tqdm

from ..sim import make_state, step
from ..sim.pbf import PARAM_NAMES
from .data import Sequence
from .losses import l1_loss, projection, projection_loss, seen

#: Typical size of each parameter (the model's defaults): the optimiser's unit.
SCALES = {"lambda_c": 0.1, "lambda_v": 60.0, "lambda_s": 0.1, "lambda_omega": 1.0}
LOSSES = ("l1", "projection")
#: Distance between batch samples simulated together, m (≫ h and the scenes' size).
OFFSET_M = 2.0
#: Gradient clipping: at most CLIP × the running mean norm (EMA weight EMA), after WARMUP iterations.
CLIP, EMA, WARMUP = 3.0, 0.1, 10
#: Fraction of the last iterates averaged into the estimate.
TAIL = 0.1


@dataclass(frozen=True)
class FitConfig:
    """How to fit. ``params``: which λ to estimate; ``init``: their starting values (missing:
    the model defaults); ``loss``: "l1" (particle correspondence) or "projection" (masks-like
    images, no correspondence); ``lr`` / ``lr_final``: Adam's learning rate anneals (cosine)
    from ``lr`` to ``lr_final`` × ``lr`` at the last iteration (the thesis's constant 1e-2 is
    ``lr=1e-2, lr_final=1``; it leaves the projection fit of λ_c 0.15, λ_v 30 9 % off);
    thesis values for the rest."""

    params: tuple = ("lambda_c", "lambda_v")
    init: dict = field(default_factory=dict)
    loss: str = "l1"
    batch: int = 8
    horizon: int = 2
    lr: float = 2e-2
    lr_final: float = 0.05
    iterations: int = 300
    seed: int = 0

    def __post_init__(self):
        bad = [p for p in self.params if p not in SCALES]
        if bad or not self.params:
            raise ValueError(f"cannot fit {bad or 'no parameters'}; fittable: {', '.join(SCALES)}")
        extra = sorted(set(self.init) - set(self.params))
        if extra:
            raise ValueError(f"init given for {extra}, which are not fitted ({', '.join(self.params)})")
        if self.loss not in LOSSES:
            raise ValueError(f"unknown loss {self.loss!r}; known: {', '.join(LOSSES)}")
        for name, lo in (("batch", 1), ("horizon", 1), ("iterations", 1)):
            if int(getattr(self, name)) < lo:
                raise ValueError(f"{name} must be at least {lo}, got {getattr(self, name)}")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise ValueError(f"lr must be > 0, got {self.lr}")
        if not (math.isfinite(self.lr_final) and 0 < self.lr_final <= 1):
            raise ValueError(f"lr_final must be in (0, 1], got {self.lr_final}")
        for k, v in self.init.items():
            if not (math.isfinite(float(v)) and float(v) >= 0):
                raise ValueError(f"initial {k} must be a finite number >= 0, got {v}")


@dataclass(frozen=True)
class FitResult:
    """``values`` / ``std``: {param: estimate, spread}; ``history``: (iterations + 1, P)
    parameter values after each iteration (row 0 = init); ``losses``: (iterations,) batch
    losses; ``wall_s``; ``particle_steps_per_s`` (forward and backward together); ``clipped``:
    iterations whose gradient was clipped."""

    params: tuple
    values: dict
    std: dict
    history: np.ndarray
    losses: np.ndarray
    wall_s: float
    particle_steps_per_s: float
    config: FitConfig
    clipped: int = 0

    def relative_error(self, truth: dict) -> dict:
        """{param: |estimate − truth| / truth}."""
        return {p: abs(self.values[p] - truth[p]) / abs(truth[p]) for p in self.params}

    def as_dict(self) -> dict:
        return {"params": list(self.params), "values": self.values, "std": self.std,
                "iterations": int(self.losses.shape[0]), "final_loss": float(self.losses[-1]), "clipped": self.clipped,
                "wall_s": self.wall_s, "particle_steps_per_s": self.particle_steps_per_s,
                "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(self.config).items()}}


class Views:
    """What the camera sees of the true states: the projection image of the visible particles
    (:func:`~.losses.seen`), computed once per step index and kept."""

    def __init__(self, seq: Sequence):
        self.seq, self._image = seq, {}

    def image(self, k: int) -> torch.Tensor:
        if k not in self._image:
            s = self.seq
            with torch.no_grad():
                self._image[k] = projection(s.camera, s.x[k], seen(s.camera, s.x[k], s.model.objects, s.poses[k]))
        return self._image[k]


def batch_loss(seq: Sequence, model, starts, cfg: FitConfig, *, spaced: bool = True,
               views: Views | None = None) -> torch.Tensor:
    """Mean over ``starts`` (true step indices) of the loss summed over the horizon.

    ``spaced``: simulate the whole batch as one state, sample b's objects and particles moved
    b·:data:`OFFSET_M` along world x (no neighbour or collision ever mixes two samples, as in
    the inference bank); else one sample after another (the reference it must equal).

    The projection loss draws the rolled-out particles the camera sees where they are now
    (visibility traced at the predicted positions and the poses of that step) and compares
    with the true state's own image, drawn the same way. Drawing the prediction with the
    start state's visibility instead (as this did before) left a loss floor at the true
    parameters from particles crossing an occluding edge during the horizon; that floor's
    gradient outweighed λ_v's and pulled λ_v fits away from 30 (3 of the 9 ladle cases)."""
    views = Views(seq) if views is None else views
    if not spaced:
        return sum(batch_loss(seq, model, [t], cfg, views=views) for t in starts) / len(starts)
    B, N, M = len(starts), seq.particles, seq.poses.shape[1]
    shift = torch.zeros(B, 1, 3, dtype=seq.x.dtype)
    shift[:, 0, 0] = torch.arange(B, dtype=seq.x.dtype) * OFFSET_M
    t = torch.as_tensor(np.asarray(starts))

    def poses_at(k):
        p = seq.poses[t + k].clone()                 # (B, M, 7)
        p[:, :, :3] += shift
        return p.reshape(B * M, 7)

    big = model.replace(objects=tuple(model.objects) * B)
    state = make_state((seq.x[t] + shift).reshape(B * N, 3), seq.v[t].reshape(B * N, 3), poses=poses_at(0),
                       dtype=seq.x.dtype)
    total = 0.0
    for k in range(1, cfg.horizon + 1):
        state = step(big, state, poses_at(k))
        x, v = state.by_id()
        x = x.reshape(B, N, 3) - shift
        if cfg.loss == "l1":
            total = total + l1_loss(x, v.reshape(B, N, 3), seq.x[t + k], seq.v[t + k], model.h, model.dt)
        else:
            total = total + sum(projection_loss(seq.camera, x[b], seen(seq.camera, x[b], seq.model.objects,
                                                                       seq.poses[int(t[b]) + k]),
                                                views.image(int(t[b]) + k)) for b in range(B)) / B
    return total


def fit(seq: Sequence, cfg: FitConfig = FitConfig(), *, progress: bool = False, desc: str = "fit") -> FitResult:
    """Estimate ``cfg.params`` from ``seq`` (see the module doc)."""
    if seq.steps <= cfg.horizon:
        raise ValueError(f"the sequence has {seq.steps} steps; the horizon {cfg.horizon} needs more")
    defaults = seq.model.params.as_dict()
    scale = torch.tensor([SCALES[p] for p in cfg.params], dtype=torch.float64)
    theta = torch.tensor([float(cfg.init.get(p, defaults[p])) for p in cfg.params], dtype=torch.float64) / scale
    theta.requires_grad_(True)
    opt = torch.optim.Adam([theta], lr=cfg.lr)
    sched = None
    if cfg.lr_final < 1:             # the last iteration runs at lr × lr_final
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, cfg.iterations - 1),
                                                           eta_min=cfg.lr * cfg.lr_final)
    rng = np.random.default_rng(cfg.seed)
    views = Views(seq)
    hist = [(theta.detach() * scale).numpy().copy()]
    losses = []
    t0 = time.perf_counter()
    bar = tqdm(range(cfg.iterations), desc=desc, unit="it", disable=not progress, leave=False)
    ema, clipped = 0.0, 0
    for it in bar:
        lam = theta * scale
        model = seq.model.with_params(**{p: lam[i] for i, p in enumerate(cfg.params)})
        starts = rng.integers(0, seq.steps - cfg.horizon + 1, size=cfg.batch)
        opt.zero_grad()
        loss = batch_loss(seq, model, starts, cfg, views=views)
        loss.backward()
        norm = float(theta.grad.norm())
        if it >= WARMUP and math.isfinite(norm) and norm > CLIP * ema:
            theta.grad.mul_(CLIP * ema / norm)
            norm, clipped = CLIP * ema, clipped + 1
        ema = norm if it == 0 else (1 - EMA) * ema + EMA * norm
        opt.step()
        if sched is not None:
            sched.step()
        with torch.no_grad():
            theta.clamp_(min=0.0)
        hist.append((theta.detach() * scale).numpy().copy())
        losses.append(float(loss.detach()))
        bar.set_postfix({p: f"{hist[-1][i]:.4g}" for i, p in enumerate(cfg.params)})
    wall = time.perf_counter() - t0
    history = np.stack(hist)
    tail = history[-max(1, int(round(TAIL * cfg.iterations))):]
    values = {p: float(tail[:, i].mean()) for i, p in enumerate(cfg.params)}
    std = {p: float(tail[:, i].std()) for i, p in enumerate(cfg.params)}
    work = cfg.iterations * cfg.batch * cfg.horizon * seq.particles
    return FitResult(tuple(cfg.params), values, std, history, np.asarray(losses), wall, work / wall, cfg, clipped)


assert set(SCALES) <= set(PARAM_NAMES)
