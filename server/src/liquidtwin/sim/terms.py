"""Extra force and constraint terms: the place to extend the physics without editing the step.

A term is a frozen dataclass whose tensor fields are its (learnable) parameters. The step
calls three hooks; each returns ``None`` (no contribution) or an (N, 3) tensor:

- ``acceleration(model, state)`` — m/s², added to gravity before prediction;
- ``position_delta(model, x, ids)`` — m, added to the constraint corrections in every
  solver iteration (particles sorted by cell; ``ids`` maps them to their original labels);
- ``velocity_delta(model, x, v, ids)`` — m/s, added after viscosity.

Discrepancy discovery adds drag, wind, adhesion, leaks … as such terms.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .sdf import min_sdf


class Term:
    """Base class: contributes nothing. Override the hooks you need."""

    name = "term"

    def acceleration(self, model, state) -> torch.Tensor | None:
        return None

    def position_delta(self, model, x: torch.Tensor, ids: torch.Tensor) -> torch.Tensor | None:
        return None

    def velocity_delta(self, model, x: torch.Tensor, v: torch.Tensor, ids: torch.Tensor) -> torch.Tensor | None:
        return None


@dataclass(frozen=True, eq=False)
class LinearDrag(Term):
    """Air drag proportional to velocity: a = −k v. ``k``: scalar tensor, 1/s."""

    k: torch.Tensor
    name = "drag"

    def acceleration(self, model, state):
        return -self.k * state.v


@dataclass(frozen=True, eq=False)
class UniformAcceleration(Term):
    """The same extra acceleration on every particle (e.g. wind). ``a``: (3,) tensor, m/s²."""

    a: torch.Tensor
    name = "wind"

    def acceleration(self, model, state):
        return self.a.to(state.v).expand_as(state.v)


@dataclass(frozen=True, eq=False)
class QuadraticDrag(Term):
    """Air drag on fast particles: a = −c |v| v. ``c``: scalar tensor, 1/m.

    For a water drop of diameter d in air, c = 3 ρ_air C_d / (4 ρ_water d) ≈ 0.2 1/m at
    d = 3 mm (C_d ≈ 0.5); streams that break up into spray see larger values.
    """

    c: torch.Tensor
    name = "drag"

    def acceleration(self, model, state):
        v = state.v
        return -self.c.to(v) * v.norm(dim=-1, keepdim=True) * v


@dataclass(frozen=True, eq=False)
class WallAdhesion(Term):
    """Particles near object surfaces are slowed: a = −k w v with w = clamp(1 − d/δ, 0, 1),
    d the signed distance to the nearest object and δ = ``distance``.

    ``k``: scalar tensor, 1/s (a film on the wall loses speed at rate k);
    ``distance``: float, m (range of the effect, about a particle spacing).
    """

    k: torch.Tensor
    distance: float
    name = "wall_adhesion"

    def acceleration(self, model, state):
        if not model.objects:
            return None
        d = min_sdf(state.x, model.objects, state.poses.to(state.x))
        w = torch.clamp(1.0 - d / self.distance, 0.0, 1.0)[:, None]
        return -self.k.to(state.v) * w * state.v


@dataclass(frozen=True, eq=False)
class LinearAcceleration(Term):
    """A learned correction linear in the velocity: a = W [v, 1]. ``W``: (3, 4) tensor
    (columns: 1/s for the velocity part, m/s² for the constant part)."""

    W: torch.Tensor
    name = "learned"

    def acceleration(self, model, state):
        W = self.W.to(state.v)
        return state.v @ W[:, :3].T + W[:, 3]
