"""Fixed-radius neighbour search on a hash grid (thesis §8.5.1, SPEC §1).

Cells have the size of the search radius, so every neighbour of a point lies in the 27
cells around its own. Cells are keyed by the *rank* of their integer coordinate along each
axis among the occupied ones, which keeps keys small for any input — a particle a
kilometre away from the others costs one more rank, not a huge grid — and makes the search
exact for every input: nothing is truncated, there is no maximum neighbour count.

Results are compressed sparse rows (CSR): the neighbours of query ``i`` are
``col[row_ptr[i]:row_ptr[i+1]]``, sorted by cell. This module is the pure-torch reference;
``liquidtwin.sim._native`` has the same search in C++/OpenMP for speed, tested against it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

_OFFSETS = torch.tensor([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])


@dataclass(frozen=True)
class Neighbors:
    """Neighbour lists in CSR form.

    Attributes:
      row_ptr: (Nq + 1,) int64 offsets into ``col``.
      col: (P,) int64 indices into the data points, one per (query, neighbour) pair.
      radius: search radius, m; every pair has distance < radius.
    """

    row_ptr: torch.Tensor
    col: torch.Tensor
    radius: float

    @property
    def num_pairs(self) -> int:
        return int(self.col.numel())

    def rows(self) -> torch.Tensor:
        """(P,) int64 query index of every pair."""
        n = self.row_ptr.numel() - 1
        counts = self.row_ptr[1:] - self.row_ptr[:-1]
        return torch.repeat_interleave(torch.arange(n, device=self.col.device), counts)

    def counts(self) -> torch.Tensor:
        """(Nq,) int64 number of neighbours of each query."""
        return self.row_ptr[1:] - self.row_ptr[:-1]


def check_points(x: torch.Tensor, name: str = "positions") -> None:
    """Raise a clear ValueError unless ``x`` is a finite (N, 3) float tensor."""
    if not isinstance(x, torch.Tensor) or x.dim() != 2 or x.shape[1] != 3:
        raise ValueError(f"{name} must be an (N, 3) tensor, got {tuple(getattr(x, 'shape', ()))}")
    if not x.is_floating_point():
        raise ValueError(f"{name} must be floating point, got {x.dtype}")
    bad = ~torch.isfinite(x).all(dim=1)
    if bool(bad.any()):
        idx = torch.nonzero(bad).flatten()[:5].tolist()
        raise ValueError(f"{name} has {int(bad.sum())} non-finite rows (first: {idx})")


def cell_coords(x: torch.Tensor, cell: float) -> torch.Tensor:
    """(N, 3) int64 integer cell coordinates of points ``x`` (N, 3), m, for cell size m."""
    return torch.floor(x.detach() / cell).to(torch.int64)


def cell_keys(x: torch.Tensor, cell: float) -> torch.Tensor:
    """(N,) int64 keys, equal iff two points share a cell and ordered x-fastest within z, y."""
    c = cell_coords(x, cell)
    key = torch.zeros(c.shape[0], dtype=torch.int64, device=c.device)
    for axis in (2, 1, 0):
        uniq, rank = torch.unique(c[:, axis], return_inverse=True)
        key = key * uniq.numel() + rank
    return key


def cell_order(x: torch.Tensor, cell: float) -> torch.Tensor:
    """(N,) int64 permutation that sorts points ``x`` (N, 3) by grid cell (stable)."""
    return torch.argsort(cell_keys(x, cell), stable=True)


def find_neighbors(
    query: torch.Tensor,
    data: torch.Tensor | None = None,
    radius: float = 0.1,
    *,
    exclude_self: bool | None = None,
) -> Neighbors:
    """All data points within ``radius`` of each query point.

    Args:
      query: (Nq, 3) query positions, m.
      data: (Nd, 3) data positions, m; ``None`` means the queries themselves.
      radius: search radius, m (> 0). Pairs with distance < radius are returned.
      exclude_self: drop the pair (i, i); defaults to True when ``data`` is None.
    Returns:
      :class:`Neighbors` with Nq rows and indices into ``data``.
    """
    if not radius > 0:
        raise ValueError(f"radius must be > 0, got {radius}")
    same = data is None
    data = query if data is None else data
    check_points(query, "query positions")
    check_points(data, "data positions")
    exclude_self = same if exclude_self is None else exclude_self
    dev = query.device
    nq = query.shape[0]
    empty = Neighbors(torch.zeros(nq + 1, dtype=torch.int64, device=dev),
                      torch.zeros(0, dtype=torch.int64, device=dev), radius)
    if nq == 0 or data.shape[0] == 0:
        return empty

    cd = cell_coords(data, radius)
    cq = cell_coords(query, radius)
    # Rank every occupied coordinate per axis; a query's neighbour cell exists only if all
    # three of its coordinates occur among the data's.
    key_d = torch.zeros(cd.shape[0], dtype=torch.int64, device=dev)
    cand = cq[:, None, :] + _OFFSETS.to(dev)[None]  # (Nq, 27, 3)
    key_q = torch.zeros(cand.shape[:2], dtype=torch.int64, device=dev)
    valid = torch.ones(cand.shape[:2], dtype=torch.bool, device=dev)
    for axis in (2, 1, 0):
        uniq, rank_d = torch.unique(cd[:, axis], return_inverse=True)
        key_d = key_d * uniq.numel() + rank_d
        pos = torch.searchsorted(uniq, cand[..., axis].contiguous()).clamp(max=uniq.numel() - 1)
        valid &= uniq[pos] == cand[..., axis]
        key_q = key_q * uniq.numel() + pos

    order = torch.argsort(key_d, stable=True)
    cells, counts = torch.unique_consecutive(key_d[order], return_counts=True)
    starts = torch.cumsum(counts, 0) - counts
    slot = torch.searchsorted(cells, key_q).clamp(max=cells.numel() - 1)
    found = valid & (cells[slot] == key_q)
    n_in = torch.where(found, counts[slot], torch.zeros_like(slot)).flatten()  # (Nq*27,)
    first = torch.where(found, starts[slot], torch.zeros_like(slot)).flatten()

    total = int(n_in.sum())
    qidx = torch.repeat_interleave(torch.arange(nq, device=dev), n_in.view(nq, 27).sum(1))
    seg_start = torch.cumsum(n_in, 0) - n_in
    within = torch.arange(total, device=dev) - torch.repeat_interleave(seg_start, n_in)
    didx = order[torch.repeat_interleave(first, n_in) + within]

    diff = query.detach()[qidx] - data.detach()[didx]
    keep = (diff * diff).sum(1) < radius * radius
    if exclude_self:
        keep &= qidx != didx
    qidx, didx = qidx[keep], didx[keep]
    row_ptr = torch.zeros(nq + 1, dtype=torch.int64, device=dev)
    row_ptr[1:] = torch.cumsum(torch.bincount(qidx, minlength=nq), 0)
    return Neighbors(row_ptr, didx, radius)


def brute_force_neighbors(
    query: torch.Tensor, data: torch.Tensor | None = None, radius: float = 0.1,
    *, exclude_self: bool | None = None,
) -> Neighbors:
    """O(Nq·Nd) reference with the same contract as :func:`find_neighbors` (for tests)."""
    same = data is None
    data = query if data is None else data
    exclude_self = same if exclude_self is None else exclude_self
    d2 = ((query.detach()[:, None, :] - data.detach()[None, :, :]) ** 2).sum(-1)
    mask = d2 < radius * radius
    if exclude_self:
        mask.fill_diagonal_(False)
    qidx, didx = torch.nonzero(mask, as_tuple=True)
    nq = query.shape[0]
    row_ptr = torch.zeros(nq + 1, dtype=torch.int64, device=query.device)
    row_ptr[1:] = torch.cumsum(torch.bincount(qidx, minlength=nq), 0)
    return Neighbors(row_ptr, didx, radius)
