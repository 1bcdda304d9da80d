"""ConvSP: the particle–particle layer of SPNets (thesis §8.2.1, SPEC §1).

``ConvSP(Xq, Xd, Y)_i = Σ_{j ∈ Xd, d_ij < h} y_j W(d_ij, h)`` for every query i — a
kernel-weighted sum of per-particle features over neighbours. Written with gathers and
``index_add`` over a CSR pair list, so autograd gives exact gradients with respect to query
positions, data positions, features and the optional learnable channel mixing. This is the
reference implementation every fused kernel is tested against.
"""

from __future__ import annotations

import torch
from torch import nn

from .kernels import KERNELS, kernel_value
from .neighbors import Neighbors, find_neighbors

_MIN_DIST = 1e-12
"""Distances are clamped here so coincident particles give finite (zero-direction) terms."""


def pair_geometry(query: torch.Tensor, data: torch.Tensor, nb: Neighbors):
    """Per-pair (rows (P,), cols (P,), r = x_i − x_j (P, 3) m, d = |r| (P,) m)."""
    rows = nb.rows()
    r = query[rows] - data[nb.col]
    d = torch.sqrt((r * r).sum(-1).clamp_min(_MIN_DIST**2))
    return rows, nb.col, r, d


def convsp(
    query: torch.Tensor,
    features: torch.Tensor,
    kernel: str,
    h: float,
    *,
    data: torch.Tensor | None = None,
    neighbors: Neighbors | None = None,
    include_self: bool = False,
    dis_norm: bool = False,
) -> torch.Tensor:
    """Kernel-weighted neighbour sum.

    Args:
      query: (Nq, 3) query positions, m.
      features: (Nd, C) or (Nd,) features y_j of the data particles.
      kernel: name in :data:`liquidtwin.sim.kernels.KERNELS`.
      h: kernel radius, m.
      data: (Nd, 3) data positions, m; ``None``: the queries themselves.
      neighbors: precomputed lists (radius >= h) for (query, data); found if ``None``.
      include_self: add y_i W(0) (only when data is the queries).
      dis_norm: use W(d)/d instead of W(d) (the \\bar W of thesis §8.2.1).
    Returns:
      (Nq, C) or (Nq,) sums, matching the feature shape.
    """
    if kernel not in KERNELS:
        raise ValueError(f"unknown kernel {kernel!r}; expected one of {KERNELS}")
    same = data is None
    data = query if data is None else data
    flat = features.dim() == 1
    y = features[:, None] if flat else features
    if y.shape[0] != data.shape[0]:
        raise ValueError(f"features have {y.shape[0]} rows but there are {data.shape[0]} data particles")
    if neighbors is None:
        neighbors = find_neighbors(query, None if same else data, h)
    elif neighbors.radius < h:
        raise ValueError(f"neighbour lists of radius {neighbors.radius} are too short for h = {h}")
    rows, cols, _, d = pair_geometry(query, data, neighbors)
    w = kernel_value(kernel, d, h)
    if dis_norm:
        w = w / d
    out = torch.zeros(query.shape[0], y.shape[1], dtype=y.dtype, device=y.device)
    out = out.index_add(0, rows, y[cols] * w[:, None])
    if include_self:
        if not same:
            raise ValueError("include_self needs data to be the queries")
        if dis_norm:
            raise ValueError("include_self is undefined with dis_norm (division by d = 0)")
        out = out + y * kernel_value(kernel, torch.zeros((), dtype=y.dtype, device=y.device), h)
    return out[:, 0] if flat else out


class ConvSP(nn.Module):
    """ConvSP as a layer: neighbour sum of each input channel, then learnable channel mixing.

    ``out = ConvSP(X, Y) @ weight.T + bias`` with ``weight`` (C_out, C_in). With the
    identity weight and zero bias it is the plain kernel sum the fluid terms use.
    """

    def __init__(self, in_channels: int, out_channels: int, kernel: str, h: float, *,
                 dis_norm: bool = False, include_self: bool = False, learnable: bool = True):
        super().__init__()
        if kernel not in KERNELS:
            raise ValueError(f"unknown kernel {kernel!r}; expected one of {KERNELS}")
        self.kernel, self.h, self.dis_norm, self.include_self = kernel, h, dis_norm, include_self
        weight = torch.eye(out_channels, in_channels)
        bias = torch.zeros(out_channels)
        if learnable:
            self.weight, self.bias = nn.Parameter(weight), nn.Parameter(bias)
        else:
            self.register_buffer("weight", weight)
            self.register_buffer("bias", bias)

    def forward(self, query: torch.Tensor, features: torch.Tensor, data: torch.Tensor | None = None,
                neighbors: Neighbors | None = None) -> torch.Tensor:
        """query (Nq, 3) m, features (Nd, C_in) → (Nq, C_out)."""
        s = convsp(query, features, self.kernel, self.h, data=data, neighbors=neighbors,
                   include_self=self.include_self, dis_norm=self.dis_norm)
        return s @ self.weight.T + self.bias
