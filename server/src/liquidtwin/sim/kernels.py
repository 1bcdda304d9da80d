"""Smoothing kernels of SPNets (thesis §8.1, SPEC §1).

Every kernel is a function of the distance ``d`` (m) and the kernel radius ``h`` (m) and
is zero for ``d >= h``. They are written for tensors (any shape, any float dtype) and are
differentiable in ``d``.

=============  ===========================================  ==========================
name           W(d, h)                                      used for
=============  ===========================================  ==========================
``rho``        15/(π h³) (1 − d/h)²                         density, viscosity
``omega``      30/(π h³) (1 − d/h) / h                      pressure (= −dW_rho/dd)
``cohesion``   a (d/h)³ + b (d/h)² − 1, dimensionless       cohesion, surface normals
``poly6``      315/(64 π h⁹) (h² − d²)³                     classic PBF density
``spiky``      15/(π h⁶) (h − d)³                           classic PBF pressure
``spiky_grad`` −45/(π h⁶) (h − d)²                          its derivative
``constant``   1                                            neighbour counts, indicator I
=============  ===========================================  ==========================

Cohesion: the thesis prints the cubic coefficient as ``−(1 − d0)/d0²``; with that value
W_c(h) = 2/d0 ≠ 0, so the kernel would jump at the cut-off. The public SPNets code uses
``−6 (d/h)³ + 7 (d/h)² − 1`` for d0 = 0.5, i.e. ``a = −(1 + d0)/d0²``, whose roots are
exactly d0·h (rest distance: repulsive below, attractive above) and h. We use that.
"""

from __future__ import annotations

import math

import torch

COHESION_D0 = 0.5
"""Zero crossing of the cohesion kernel as a fraction of h."""

KERNELS = ("rho", "omega", "cohesion", "poly6", "spiky", "spiky_grad", "constant")


def cohesion_coefficients(d0: float = COHESION_D0) -> tuple[float, float]:
    """(a, b) such that W_c(x) = a x³ + b x² − 1 has roots at x = d0 and x = 1."""
    b = (d0 * d0 + d0 + 1.0) / (d0 * d0)
    return 1.0 - b, b


def kernel_value(name: str, d: torch.Tensor, h: float) -> torch.Tensor:
    """W(d, h) for kernel ``name``; zero where ``d >= h``.

    Args:
      name: one of :data:`KERNELS`.
      d: (...) distances, m, >= 0.
      h: kernel radius, m.
    Returns:
      (...) kernel values, same dtype as ``d``.
    """
    inside = d < h
    x = (d / h).clamp(max=1.0)
    if name == "rho":
        w = 15.0 / (math.pi * h**3) * (1.0 - x) ** 2
    elif name == "omega":
        w = 30.0 / (math.pi * h**4) * (1.0 - x)
    elif name == "cohesion":
        a, b = cohesion_coefficients()
        w = (a * x + b) * x * x - 1.0
    elif name == "poly6":
        w = 315.0 / (64.0 * math.pi * h**9) * (h * h - (x * h) ** 2) ** 3
    elif name == "spiky":
        w = 15.0 / (math.pi * h**6) * (h - x * h) ** 3
    elif name == "spiky_grad":
        w = -45.0 / (math.pi * h**6) * (h - x * h) ** 2
    elif name == "constant":
        w = torch.ones_like(d)
    else:
        raise ValueError(f"unknown kernel {name!r}; expected one of {KERNELS}")
    return torch.where(inside, w, torch.zeros_like(w))
