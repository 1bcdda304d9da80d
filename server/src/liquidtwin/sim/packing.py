"""Rest packing of fluid particles and the self-consistent calibration built on it.

The lattice is the one the public SPNets code calibrates with: rows along x at the rest
spacing s, offset by s/2 on alternate (y + z) parity, rows and layers √0.75·s apart. Every
particle has its nearest neighbours exactly s away and occupies 0.75·s³ of liquid.
Rest density and pressure stiffness are read off this lattice, and containers are filled
with the same lattice, so liquid starts exactly at rest density.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .kernels import kernel_value

ROW = math.sqrt(0.75)


def lattice(lo, hi, spacing: float) -> np.ndarray:
    """(N, 3) float64 lattice points inside the box [lo, hi] (m) at rest ``spacing`` (m)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    if np.any(hi < lo) or not spacing > 0:
        raise ValueError(f"bad lattice box {lo}..{hi} or spacing {spacing}")
    ny = int(np.floor((hi[1] - lo[1]) / (ROW * spacing))) + 1
    nz = int(np.floor((hi[2] - lo[2]) / (ROW * spacing))) + 1
    pts = []
    for k in range(nz):
        for j in range(ny):
            off = 0.5 * spacing if (j + k) & 1 else 0.0
            xs = np.arange(lo[0] + off, hi[0] + 1e-12, spacing)
            if xs.size:
                pts.append(np.stack([xs, np.full_like(xs, lo[1] + j * ROW * spacing),
                                     np.full_like(xs, lo[2] + k * ROW * spacing)], 1))
    return np.concatenate(pts, 0) if pts else np.zeros((0, 3))


def particle_volume(spacing: float) -> float:
    """Liquid volume one particle stands for in the rest lattice, m³."""
    return 0.75 * spacing**3


def particle_radius(spacing: float) -> float:
    """Radius of the sphere one particle stands for, m: the rest volume 0.75 s³ as a ball."""
    return (3.0 * 0.75 * spacing**3 / (4.0 * math.pi)) ** (1.0 / 3.0)


def calibrate(h: float, spacing: float) -> tuple[float, float]:
    """(ρ0, κ) from a particle in the rest lattice: ρ0 = Σ_j W_ρ(d_j) (unit mass, self
    excluded, kernel units m⁻³) and κ = 1 / Σ_j W_ω(d_j)², the stiffness that makes one
    pressure iteration undo a uniform density excess (as in the public SPNets code)."""
    n = int(math.ceil(h / spacing)) + 1
    pts = lattice([-n * spacing] * 3, [n * spacing] * 3, spacing)
    # Re-centre on the lattice site closest to the origin.
    centre = pts[np.argmin(np.linalg.norm(pts, axis=1))]
    d = np.linalg.norm(pts - centre, axis=1)
    d = torch.from_numpy(d[(d > 1e-12) & (d < h)])
    rho0 = float(kernel_value("rho", d, h).sum())
    kappa = 1.0 / float((kernel_value("omega", d, h) ** 2).sum())
    return rho0, kappa
