"""Model-predictive control with gradients through SPNets (thesis §8.3.3, SPEC §7).

At every update the controller rolls the model ``horizon`` steps from the current particle
state under its planned controls u_t … u_{t+T−1} (object poses from a :class:`ControlSpace`),
sums the task loss over the horizon, takes the gradient with respect to *every* planned
control, and moves each by a fixed step against its own normalised gradient::

    u_i ← clip(u_i − s · ∇u_i / ‖∇u_i‖, −rate limit, +rate limit)

The first control is executed; the plan shifts by one (the last is repeated). Controls are
velocities (rad/s or m/s); their integral (angle or position) is clamped to the control
space's limits inside the rollout, so the plan never relies on motion the robot may not make.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import torch

from ..sim import FluidModel, FluidState, step


class ControlError(ValueError):
    """A task or control request that cannot be served (says why)."""


def by_ids(state: FluidState, ids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(x, v) of the particles labelled ``ids`` (K,), in that order (differentiable).

    A task picks its particles on the current state (``state.ids[mask]`` for a row mask such
    as :func:`liquidtwin.scenes.liquid_level.held`'s) and finds them again by label in every
    rolled-out state: the simulator re-sorts rows by grid cell each step, so row numbers do
    not carry over (and are not ``by_id()`` positions once particles have been removed)."""
    order = torch.argsort(state.ids)
    rows = order[torch.searchsorted(state.ids[order], ids.to(state.ids))]
    return state.x[rows], state.v[rows]


@dataclass
class ControlSpace:
    """How controls move the scene.

    Attributes:
      base_poses: (M, 7) poses of every object (those not controlled stay there).
      index: the controlled object.
      to_pose: (positions (T, D)) → (T, 7) poses of the controlled object; differentiable.
      lower, upper: (D,) limits of the integrated control (angle rad or position m).
      max_rate: (D,) limits of the control itself (rad/s or m/s).
    """

    base_poses: torch.Tensor
    index: int
    to_pose: Callable
    lower: torch.Tensor
    upper: torch.Tensor
    max_rate: torch.Tensor

    @property
    def dims(self) -> int:
        return int(self.max_rate.numel())

    def positions(self, q0: torch.Tensor, u: torch.Tensor, dt: float) -> torch.Tensor:
        """(T, D) integrated positions after each control of u (T, D) from q0 (D,), clamped
        to the limits (the clamp passes no gradient where a limit is reached)."""
        return torch.minimum(torch.maximum(q0 + dt * torch.cumsum(u, 0), self.lower), self.upper)

    def poses(self, q: torch.Tensor) -> torch.Tensor:
        """(T, M, 7) scene poses for controlled positions q (T, D)."""
        out = self.base_poses.to(q.dtype).expand(q.shape[0], -1, -1).clone()
        out[:, self.index] = self.to_pose(q)
        return out


@dataclass
class MPC:
    """The controller (module doc). ``loss(state, k, q)`` → scalar tensor: the task loss of
    the state after planned step k (0-based) of the horizon, q (D,) the controlled object's
    positions then (angles, m). ``step_size``: s, in control
    units per update."""

    model: FluidModel
    space: ControlSpace
    loss: Callable
    horizon: int = 10
    step_size: float = 0.1
    plan: torch.Tensor = field(default=None)

    def __post_init__(self):
        if self.horizon < 1:
            raise ControlError(f"horizon must be at least 1 step, got {self.horizon}")
        if not (math.isfinite(self.step_size) and self.step_size > 0):
            raise ControlError(f"step_size must be > 0, got {self.step_size}")
        if self.plan is None:
            self.plan = torch.zeros(self.horizon, self.space.dims, dtype=torch.float64)

    def horizon_loss(self, state: FluidState, q0: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Σ_k loss(state after planned step k) for controls u (T, D) from positions q0."""
        q = self.space.positions(q0, u, self.model.dt)
        poses = self.space.poses(q).to(state.x)
        s = FluidState(state.x.detach(), state.v.detach(), state.ids, state.poses, state.t)
        total = 0.0
        for k in range(u.shape[0]):
            s = step(self.model, s, poses[k])
            total = total + self.loss(s, k, q[k])
        return total

    def skip(self, steps: int) -> None:
        """Move the plan on by ``steps`` − 1 more steps (:meth:`update` shifts one): for a
        caller that updates once every ``steps`` model steps (a session, once per frame)."""
        if steps > 1:
            k = min(int(steps) - 1, self.plan.shape[0] - 1)
            self.plan = torch.cat([self.plan[k:], self.plan[-1:].expand(k, -1)])

    def update(self, state: FluidState, q0: torch.Tensor) -> tuple[torch.Tensor, float]:
        """One gradient step on the whole plan; returns (the control to execute now (D,),
        the horizon loss before the step). The plan then shifts by one."""
        u = self.plan.clone().requires_grad_(True)
        loss = self.horizon_loss(state, q0.to(torch.float64), u)
        (grad,) = torch.autograd.grad(loss, u, allow_unused=True)
        with torch.no_grad():
            if grad is not None:
                norm = grad.norm(dim=1, keepdim=True)
                u = u - self.step_size * torch.where(norm > 0, grad / norm.clamp_min(1e-30), torch.zeros_like(grad))
            u = torch.maximum(torch.minimum(u.detach(), self.space.max_rate), -self.space.max_rate)
        first = u[0].clone()
        self.plan = torch.cat([u[1:], u[-1:]])
        return first, float(loss.detach())
