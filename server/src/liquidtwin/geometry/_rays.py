"""Ray queries on triangle meshes in plain NumPy (no rtree/embree needed).

* :func:`column_hits`: every crossing of vertical lines (x, z) = const with the surface,
  found through a bin grid over the columns. Columns are moved by a fixed sub-micrometre
  offset so that a line never runs exactly through an edge or a vertex (meshes built on
  round numbers would otherwise hit edges head on and count them twice).
* :func:`inside`: point-in-solid by the parity of crossings above each point (exact for a
  closed mesh).
* :func:`occupancy`: the same on the centres of a voxel grid.
* :func:`first_hit`: distance along arbitrary rays to the first triangle (Möller–Trumbore).
"""

from __future__ import annotations

import numpy as np

_JITTER = np.array([3.0e-8 * np.pi, 2.0e-8 * np.e])   # m, off any round coordinate
_MAX_PAIRS = 1 << 21


def _expand(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For counts (n,) → (owner (Σ,), rank within owner (Σ,))."""
    owner = np.repeat(np.arange(len(counts)), counts)
    start = np.cumsum(counts) - counts
    return owner, np.arange(len(owner)) - start[owner]


def column_hits(vertices: np.ndarray, faces: np.ndarray,
                xz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Crossings of vertical lines with a triangle surface.

    Args:
      vertices: (V, 3) m. faces: (F, 3) int. xz: (C, 2) line positions (x, z), m.
    Returns:
      (column (K,) int, y (K,) m) for every crossing, sorted by column then height.
    """
    tri = np.asarray(vertices, float)[np.asarray(faces)]
    q = np.asarray(xz, float).reshape(-1, 2) + _JITTER
    if len(q) == 0 or len(tri) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    ax, az = tri[:, :, 0], tri[:, :, 2]
    area = ((ax[:, 1] - ax[:, 0]) * (az[:, 2] - az[:, 0])
            - (az[:, 1] - az[:, 0]) * (ax[:, 2] - ax[:, 0]))
    tri, ax, az, area = tri[area != 0], ax[area != 0], az[area != 0], area[area != 0]
    lo = q.min(0)
    span = np.maximum(q.max(0) - lo, 1e-9)
    nb = np.ceil(span / span.max() * np.sqrt(len(q) / 2.0))
    nb = np.clip(nb, 1, 512).astype(int)
    size = span / nb * (1 + 1e-9)
    kq = np.minimum(((q - lo) / size).astype(int), nb - 1)
    key = kq[:, 0] * nb[1] + kq[:, 1]
    order = np.argsort(key, kind="stable")
    bounds = np.searchsorted(key[order], np.arange(nb[0] * nb[1] + 1))
    fmin = np.stack([ax.min(1), az.min(1)], 1)
    fmax = np.stack([ax.max(1), az.max(1)], 1)
    b0 = np.clip(np.floor((fmin - lo) / size).astype(int), 0, nb - 1)
    b1 = np.clip(np.floor((fmax - lo) / size).astype(int), 0, nb - 1)
    hit_face = (fmax >= lo - 1e-12).all(1) & (fmin <= lo + span + 1e-12).all(1)
    nbins = np.where(hit_face, (b1[:, 0] - b0[:, 0] + 1) * (b1[:, 1] - b0[:, 1] + 1), 0)
    cols, ys = [], []
    f_all, r_all = _expand(nbins)
    wz = b1[f_all, 1] - b0[f_all, 1] + 1
    bin_key = (b0[f_all, 0] + r_all // wz) * nb[1] + b0[f_all, 1] + r_all % wz
    n_in_bin = bounds[bin_key + 1] - bounds[bin_key]
    edges = np.concatenate([[0], np.cumsum(n_in_bin)])
    start = 0
    while start < len(f_all):
        stop = int(np.searchsorted(edges, edges[start] + _MAX_PAIRS, side="right")) - 1
        stop = max(start + 1, stop)
        pair, rank = _expand(n_in_bin[start:stop])
        pair += start
        f = f_all[pair]
        c = order[bounds[bin_key[pair]] + rank]
        px, pz = q[c, 0], q[c, 1]
        w = []
        for i, j in ((1, 2), (2, 0), (0, 1)):     # barycentric weight of the third vertex
            w.append(((ax[f, j] - ax[f, i]) * (pz - az[f, i])
                      - (az[f, j] - az[f, i]) * (px - ax[f, i])) / area[f])
        w = np.stack(w, 1)
        ok = (w >= 0).all(1)
        cols.append(c[ok])
        ys.append((w[ok] * tri[f[ok], :, 1]).sum(1))
        start = stop
    if not cols:                              # no face spans any query column
        return np.zeros(0, np.int64), np.zeros(0)
    col, y = np.concatenate(cols), np.concatenate(ys)
    o = np.lexsort((y, col))
    return col[o], y[o]


def crossings_above(col: np.ndarray, y: np.ndarray, query_col: np.ndarray,
                    query_y: np.ndarray) -> np.ndarray:
    """Number of crossings (col, y sorted as from :func:`column_hits`) above each query point."""
    if len(col) == 0:
        return np.zeros(len(query_col), np.int64)
    base = min(y.min(), query_y.min()) - 1.0
    step = 2.0 * (max(y.max(), query_y.max()) - base) + 1.0
    hits = col * step + (y - base)
    queries = query_col * step + (query_y - base)
    end = np.searchsorted(col, query_col, side="right")
    return end - np.searchsorted(hits, queries, side="right")


def inside(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) bool: points (N, 3) m inside the closed surface (odd number of crossings above)."""
    points = np.asarray(points, float).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0, bool)
    xz, col = np.unique(points[:, [0, 2]], axis=0, return_inverse=True)
    hcol, hy = column_hits(vertices, faces, xz)
    return crossings_above(hcol, hy, col.reshape(-1), points[:, 1]) % 2 == 1


def occupancy(vertices: np.ndarray, faces: np.ndarray, lo, cell: float, shape) -> np.ndarray:
    """(nx, ny, nz) bool: which voxel centres lo + (i + ½)·cell lie inside the closed surface."""
    nx, ny, nz = shape
    lo = np.asarray(lo, float)
    cx = lo[0] + (np.arange(nx) + 0.5) * cell
    cz = lo[2] + (np.arange(nz) + 0.5) * cell
    xz = np.stack(np.meshgrid(cx, cz, indexing="ij"), -1).reshape(-1, 2)
    col, y = column_hits(vertices, faces, xz)
    # a crossing toggles every voxel centre above... counting from the top: centre j is inside
    # when the crossings above it are odd; add one toggle at the first centre below each hit.
    j = np.clip(np.floor((y - lo[1]) / cell - 0.5).astype(int), -1, ny - 1)
    toggles = np.zeros((nx * nz, ny + 1), np.int64)
    np.add.at(toggles, (col, j + 1), 1)
    above = np.cumsum(toggles[:, ::-1], axis=1)[:, ::-1]     # crossings with index ≥ k
    occ = above[:, 1:] % 2 == 1                              # centre j ↔ crossings at j+1..
    return occ.reshape(nx, nz, ny).transpose(0, 2, 1)


def first_hit(origins: np.ndarray, directions: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
              t_min: float = 0.0) -> np.ndarray:
    """Distance (R,) m along unit rays (R, 3) from origins (R, 3) to the first triangle beyond
    ``t_min`` (inf where the ray escapes). Brute force, chunked."""
    tri = np.asarray(vertices, float)[np.asarray(faces)]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = np.full(len(origins), np.inf)
    step = max(1, _MAX_PAIRS // max(1, len(tri)))
    for s in range(0, len(origins), step):
        o, d = origins[s:s + step, None, :], directions[s:s + step, None, :]
        p = np.cross(d, e2)
        det = (p * e1).sum(-1)
        det = np.where(np.abs(det) < 1e-18, np.nan, det)
        tv = o - a
        u = (tv * p).sum(-1) / det
        qv = np.cross(tv, e1)
        v = (d * qv).sum(-1) / det
        t = (e2 * qv).sum(-1) / det
        ok = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > t_min)
        out[s:s + step] = np.where(ok, t, np.inf).min(1)
    return out
