"""Low-level construction of closed triangle meshes without boolean operations.

Two builders cover every procedural model:

* :class:`Builder` revolves (r, y) profiles about the y axis on a structured grid of rings,
  can cut rectangular holes out of a revolved wall and join holes with swept tubes (mug and
  pan handles, ladle handle). Every vertex is shared by construction, so the result is
  watertight without a union.
* :func:`boxes_mesh` makes the boundary of a union/difference of axis-aligned boxes on the
  rectilinear grid of their faces (basin, pipe junction): exact and watertight.

Units are m, object frame, y up. Profiles are polylines of (r, y) points.
"""

from __future__ import annotations

import numpy as np
import trimesh


def offset_profile(inner: np.ndarray, distance: float) -> np.ndarray:
    """Offset an open (r, y) polyline (P, 2) by ``distance`` m to its right-hand side.

    Walking from the axis along the inner surface of a container (floor, then wall up to the
    rim), the right-hand side is the material: the result is the outer surface of a wall of
    constant normal thickness. Corners are mitred, so each straight piece stays exactly
    ``distance`` from its inner counterpart.
    """
    p = np.asarray(inner, float)
    d = np.diff(p, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    n = np.stack([d[:, 1], -d[:, 0]], 1)             # right-hand normals of the segments
    out = np.empty_like(p)
    out[0] = p[0] + distance * n[0]
    if p[0, 0] == 0.0:                  # on the axis the surface of revolution is horizontal
        out[0] = [0.0, p[0, 1] - distance]
    out[-1] = p[-1] + distance * n[-1]
    for i in range(1, len(p) - 1):
        a, b = n[i - 1], n[i]
        out[i] = p[i] + distance * (a + b) / (1.0 + float(a @ b))
    return out


def subdivide(points, step: float) -> np.ndarray:
    """Insert points along an (P, 2) polyline so no segment is longer than ``step`` m."""
    p = np.asarray(points, float)
    out = [p[0]]
    for a, b in zip(p[:-1], p[1:]):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step - 1e-9)))
        out.extend(a + (b - a) * (k / n) for k in range(1, n + 1))
    return np.array(out)


class Builder:
    """Collects vertices and faces; turns them into a checked, outward-oriented trimesh."""

    def __init__(self):
        self._v: list[np.ndarray] = []
        self._f: list[np.ndarray] = []
        self._n = 0

    def vertices(self, v) -> np.ndarray:
        """Add (k, 3) vertices, return their (k,) indices."""
        v = np.asarray(v, float).reshape(-1, 3)
        self._v.append(v)
        self._n += len(v)
        return np.arange(self._n - len(v), self._n)

    def coords(self, idx) -> np.ndarray:
        """(k, 3) positions of vertex indices ``idx`` (k,)."""
        return np.concatenate(self._v)[np.asarray(idx)]

    def triangles(self, f) -> None:
        self._f.append(np.asarray(f, np.int64).reshape(-1, 3))

    def quads(self, q) -> None:
        q = np.asarray(q, np.int64).reshape(-1, 4)
        self.triangles(np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))

    def revolve(self, profile, sections: int, holes=()) -> np.ndarray:
        """Revolve an (r, y) profile (P, 2) that starts and ends on the axis (r = 0).

        Section j sits at angle θ_j = 2π j / S + θ0 about +y, measured from +x towards +z.
        ``holes`` lists quad blocks ((row0, row1), (col0, col1)) to leave out (rows count
        the bands between consecutive rings); θ0 centres the first block's columns on +x.

        Returns:
          (P - 2, S) vertex indices of the rings (profile points 1 … P-2).
        """
        p = np.asarray(profile, float)
        if abs(p[0, 0]) > 1e-12 or abs(p[-1, 0]) > 1e-12 or np.any(p[1:-1, 0] <= 0):
            raise ValueError("a revolved profile must start and end on the axis and stay off it "
                             "in between")
        theta0 = -np.pi * sum(holes[0][1]) / sections if holes else 0.0
        th = 2 * np.pi * np.arange(sections) / sections + theta0
        r, y = p[1:-1, 0:1], np.broadcast_to(p[1:-1, 1:2], (len(p) - 2, sections))
        rings = self.vertices(np.stack([r * np.cos(th), y, r * np.sin(th)], -1).reshape(-1, 3))
        rings = rings.reshape(len(r), sections)
        pole0, pole1 = self.vertices([[0.0, p[0, 1], 0.0], [0.0, p[-1, 1], 0.0]])
        nxt = np.roll(np.arange(sections), -1)
        self.triangles(np.stack([np.full(sections, pole0), rings[0], rings[0, nxt]], 1))
        self.triangles(np.stack([np.full(sections, pole1), rings[-1, nxt], rings[-1]], 1))
        i, j = np.meshgrid(np.arange(len(r) - 1), np.arange(sections), indexing="ij")
        keep = np.ones(i.shape, bool)
        for rows, cols in holes:
            keep &= ~((i >= rows[0]) & (i < rows[1]) & (j >= cols[0]) & (j < cols[1]))
        i, j = i[keep], j[keep]
        quads = [rings[i, j], rings[i + 1, j], rings[i + 1, nxt[j]], rings[i, nxt[j]]]
        self.quads(np.stack(quads, 1))
        return rings

    def tube(self, loops: list[np.ndarray], cap_end: bool = False) -> None:
        """Join consecutive vertex loops (each (L,) indices, same L, matching order) with quads;
        optionally close the last loop with a fan around its centroid. Oriented to match a
        revolved wall whose hole is walked as :func:`hole_loop` walks it."""
        for a, b in zip(loops[:-1], loops[1:]):
            nb = np.roll(np.arange(len(a)), -1)
            self.quads(np.stack([a[nb], a, b, b[nb]], 1))
        if cap_end:
            last = loops[-1]
            centre = self.vertices(self.coords(last).mean(0))[0]
            self.triangles(np.stack([np.full(len(last), centre), np.roll(last, -1), last], 1))

    def mesh(self, what: str) -> trimesh.Trimesh:
        """The assembled mesh: duplicates merged, faces wound consistently and outward."""
        m = trimesh.Trimesh(np.concatenate(self._v), np.concatenate(self._f), process=True)
        if not m.is_winding_consistent:
            trimesh.repair.fix_winding(m)
        if m.volume < 0:
            m.invert()
        if not (m.is_watertight and m.is_winding_consistent):
            raise RuntimeError(f"internal error: the {what} mesh is not closed")
        return m


def hole_loop(rings: np.ndarray, rows, cols) -> tuple[np.ndarray, np.ndarray]:
    """Boundary of the quad block rows × cols of a revolved grid, as (loop (L,) indices,
    (L, 2) integer (ring, column) positions), walked round the block."""
    (r0, r1), (c0, c1) = rows, cols
    pos = [(r0, c) for c in range(c0, c1 + 1)] + [(r, c1) for r in range(r0 + 1, r1 + 1)]
    pos += [(r1, c) for c in range(c1 - 1, c0 - 1, -1)] + [(r, c0) for r in range(r1 - 1, r0, -1)]
    pos = np.array(pos)
    return rings[pos[:, 0], pos[:, 1]], pos


def sweep_loops(builder: Builder, local_uv: np.ndarray, path: np.ndarray) -> list[np.ndarray]:
    """Rings of a tube along a planar path in the x–y plane (P, 2) as (x, y) points.

    A ring point with local coordinates (u, v) sits at path + u·ẑ + v·N, N the path tangent
    turned 90° counter-clockwise in the x–y plane (for a path leaving along +x, N = +y).
    """
    path = np.asarray(path, float)
    tangent = np.gradient(path, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], 1)
    loops = []
    for c, n in zip(path, normal):
        xy = c + local_uv[:, 1:2] * n
        loops.append(builder.vertices(np.stack([xy[:, 0], xy[:, 1], local_uv[:, 0]], 1)))
    return loops


def boxes_mesh(boxes, what: str) -> trimesh.Trimesh:
    """Closed surface of a solid built from axis-aligned boxes applied in order.

    Args:
      boxes: sequence of (lo (3,), hi (3,), solid: bool); a later box overrides an earlier
        one where they overlap (solid adds material, not solid carves it away).
    The boundary is taken on the rectilinear grid of all box faces, so it is exact.
    """
    axes = [np.unique(np.concatenate([[b[0][a], b[1][a]] for b in boxes])) for a in range(3)]
    centres = [0.5 * (ax[1:] + ax[:-1]) for ax in axes]
    cx, cy, cz = np.meshgrid(*centres, indexing="ij")
    solid = np.zeros(cx.shape, bool)
    for lo, hi, value in boxes:
        inside = ((cx > lo[0]) & (cx < hi[0]) & (cy > lo[1]) & (cy < hi[1])
                  & (cz > lo[2]) & (cz < hi[2]))
        solid[inside] = value
    shape = tuple(len(ax) for ax in axes)
    vid = np.arange(np.prod(shape)).reshape(shape)
    quads = []
    for a in range(3):
        pad = [(0, 0)] * 3
        pad[a] = (1, 1)
        s = np.pad(solid, pad)
        lo_side = np.take(s, range(s.shape[a] - 1), axis=a)
        hi_side = np.take(s, range(1, s.shape[a]), axis=a)
        for sign, where in ((1, lo_side & ~hi_side), (-1, ~lo_side & hi_side)):
            idx = np.argwhere(where)            # grid-plane index along a = idx[:, a]
            b, c = [k for k in range(3) if k != a]
            corners = []
            for db, dc in ((0, 0), (1, 0), (1, 1), (0, 1)):
                g = idx.copy()
                g[:, b] += db
                g[:, c] += dc
                corners.append(vid[g[:, 0], g[:, 1], g[:, 2]])
            q = np.stack(corners, 1)
            quads.append(q if sign > 0 else q[:, ::-1])
    q = np.concatenate(quads)
    verts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    builder = Builder()
    builder.vertices(verts)
    builder.quads(q)
    return builder.mesh(what)
