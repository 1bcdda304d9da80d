"""mesh_sdf_grid against independent references: trimesh's closest points, analytic SDFs
(sphere, box, sealed box, cup), brute force O(P·T) distances and solid-angle winding numbers."""

import math
import warnings

import numpy as np
import pytest
import torch
import trimesh

from liquidtwin.geometry import mesh_sdf as M
from liquidtwin.geometry.mesh_sdf import mesh_sdf_grid, point_triangle_distance, sdf_cache_key
from liquidtwin.scenes import shapes


def _nodes(grid) -> np.ndarray:
    """(nx, ny, nz, 3) object-frame node positions of an SDFGrid, float64 m."""
    o = grid.origin.double().numpy()
    axes = [o[a] + grid.cell * np.arange(n) for a, n in enumerate(grid.values.shape)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1)


def _winding_vos(points: np.ndarray, mesh: trimesh.Trimesh) -> np.ndarray:
    """Generalized winding number: sum of solid angles (Van Oosterom–Strackee), brute force."""
    tri = mesh.triangles
    out = np.empty(len(points))
    for i in range(0, len(points), 512):
        a, b, c = (tri[None, :, k] - points[i:i + 512, None] for k in range(3))
        la, lb, lc = (np.linalg.norm(q, axis=-1) for q in (a, b, c))
        det = np.einsum("...i,...i", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("...i,...i", a, b) * lc + np.einsum("...i,...i", b, c) * la
               + np.einsum("...i,...i", c, a) * lb)
        out[i:i + 512] = np.arctan2(det, den).sum(1) / (2 * np.pi)
    return out


def _cup_mesh(radius, height, wall, sections) -> trimesh.Trimesh:
    """Thin-walled cup revolved about y (standing on y = 0, open at the top)."""
    return shapes.cup_mesh(radius, height, wall, sections)


def _octahedron(a: float) -> trimesh.Trimesh:
    v = np.array([[a, 0, 0], [-a, 0, 0], [0, a, 0], [0, -a, 0], [0, 0, a], [0, 0, -a]])
    f = [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
         [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    mesh = trimesh.Trimesh(v, f, process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


# --- point–triangle distance --------------------------------------------------------------------

def test_point_triangle_distance_matches_trimesh_in_every_voronoi_region():
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(40, 3, 3))
    tri[0] = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]  # right triangle in z = 0 for hand-made regions
    hand_made = [[0.2, 0.2, 0.5], [-1, -1, 0.3], [2, 0, -0.1], [0.5, -1, 0], [1, 1, 0.2]]
    pts = np.concatenate([rng.normal(size=(300, 3)) * 2, hand_made])
    got = point_triangle_distance(torch.tensor(pts), torch.tensor(tri)).numpy()
    P, T = np.repeat(pts, len(tri), 0), np.tile(tri, (len(pts), 1, 1))
    ref = np.linalg.norm(trimesh.triangles.closest_point(T, P) - P, axis=1).reshape(len(pts), -1)
    assert np.abs(got - ref).max() < 1e-12
    # the hand-made points hit the face, vertex a, vertex b, edge ab and edge bc regions
    assert np.allclose(got[-5:, 0], [0.5, math.sqrt(2.09), math.sqrt(1.01), 1.0, math.sqrt(0.54)])


def test_degenerate_triangles_are_segments_and_points():
    seg = torch.tensor([[[0.0, 0, 0], [2, 0, 0], [1, 0, 0]]])  # collinear: the segment [0, 2] on x
    dot = torch.tensor([[[1.0, 1, 1]] * 3])
    p = torch.tensor([[1.0, 0.5, 0], [3, 0, 0], [-1, 1, 0], [1, 1, 1]])
    d_seg = point_triangle_distance(p, seg)[:, 0]
    assert torch.allclose(d_seg, torch.tensor([0.5, 1.0, math.sqrt(2), math.sqrt(2)]))
    d_dot = point_triangle_distance(p, dot)[:, 0]
    assert torch.allclose(d_dot, (p - 1).norm(dim=-1))


# --- distances against analytic shapes ----------------------------------------------------------

def test_icosphere_within_its_faceting_bound_of_the_sphere(tmp_path):
    R = 0.05
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=R)
    grid = mesh_sdf_grid(mesh, thickness=0.016, name="ball", cache_dir=False)
    assert grid.cell == 0.004 and grid.name == "ball"
    p = _nodes(grid)
    # The polytope lies between the ball of radius R - s (s: largest depth of a face plane
    # below the sphere) and the sphere; signed distance is monotone under inclusion, so
    # 0 <= sdf_mesh - sdf_sphere <= s at every point.
    s = R - np.abs((mesh.face_normals * mesh.triangles[:, 0]).sum(-1)).min()
    err = grid.values.double().numpy() - shapes.sphere(p, R)
    assert 1e-4 < s < 1e-3
    assert err.min() > -1e-7 and err.max() < s + 1e-7
    assert err.max() > 0.5 * s  # the bound is tight: the faceting is really seen
    # the grid covers the bounds plus 3 cells
    assert np.allclose(p[0, 0, 0], -R - 3 * grid.cell)
    assert (p[-1, -1, -1] >= R + 3 * grid.cell - 1e-9).all()


@pytest.mark.parametrize("angle", [0.0, 0.7])
def test_box_matches_analytic_box_exactly_near_faces_edges_and_corners(angle):
    half = np.array([0.031, 0.0187, 0.0243])
    centre = np.array([0.0013, -0.0007, 0.0021])
    mesh = trimesh.creation.box(extents=2 * half)
    rot = trimesh.transformations.rotation_matrix(angle, [1, 2, 3])
    mesh.apply_transform(trimesh.transformations.translation_matrix(centre) @ rot)
    grid = mesh_sdf_grid(mesh, thickness=0.01, cell=0.002, name="box", cache_dir=False)
    p = _nodes(grid)
    local = (p - centre) @ rot[:3, :3]  # node positions in the box's own axes
    ref = shapes.box(local, half)
    assert np.abs(grid.values.double().numpy() - ref).max() < 1e-6
    # the grid really probes the edge and corner regions (outside in 2 or 3 axes at once)
    out_axes = (np.abs(local) > half).sum(-1)
    assert (out_axes == 2).sum() > 100 and (out_axes == 3).sum() > 100


def test_sealed_box_cavity_is_outside_and_exact():
    outer = trimesh.creation.box(extents=(0.06, 0.05, 0.04))
    inner = trimesh.creation.box(extents=(0.05, 0.04, 0.03))
    inner.invert()
    mesh = trimesh.util.concatenate([outer, inner])
    grid = mesh_sdf_grid(mesh, thickness=0.005, cache_dir=False)
    ref = shapes.sealed_box(_nodes(grid), (0.025, 0.02, 0.015), 0.005)
    assert np.abs(grid.values.double().numpy() - ref).max() < 1e-6
    assert (ref > 0.005).sum() > 100  # cavity nodes well inside, correctly positive


def test_revolved_thin_cup_sign_and_distance_against_analytic_cup():
    r, h, w, sections = 0.03, 0.06, 0.003, 48
    mesh = _cup_mesh(r, h, w, sections)
    grid = mesh_sdf_grid(mesh, thickness=w, name="cup", cache_dir=False)  # cell 0.75 mm
    p = _nodes(grid)
    got = grid.values.double().numpy()
    ref = shapes.cup(p, r, h, w)
    # facets are chords of the analytic circles: the surfaces are within this of each other
    s = (r + w) * (1 - math.cos(math.pi / sections))
    far = np.abs(ref) > s + 1e-7
    assert (np.sign(got[far]) == np.sign(ref[far])).all()
    radial = np.linalg.norm(p[..., [0, 2]], axis=-1)
    in_wall = (ref < -1e-4) & (radial > r)
    cavity = (ref > 1e-4) & (radial < r) & (p[..., 1] > w) & (p[..., 1] < h)
    outside = (ref > 1e-4) & ((radial > r + w) | (p[..., 1] < 0))
    assert in_wall.sum() > 1000 and cavity.sum() > 10000 and outside.sum() > 10000
    assert (got[in_wall] < 0).all() and (got[cavity] > 0).all() and (got[outside] > 0).all()
    # The CSG reference is exact except above the opening (rim corners): compare elsewhere.
    exact = ~((radial < r + 2 * grid.cell) & (p[..., 1] > h - 2 * grid.cell))
    assert np.abs(got - ref)[exact].max() < 2 * s + 1e-6


# --- culling and sign against brute force -------------------------------------------------------

def _brute(mesh, grid):
    p = _nodes(grid).reshape(-1, 3)
    d = point_triangle_distance(torch.tensor(p), torch.tensor(mesh.triangles)).min(1).values.numpy()
    return d.reshape(grid.values.shape), _winding_vos(p, mesh).reshape(grid.values.shape)


CELL = 2.0**-9  # ≈ 2 mm; dyadic, so grid columns pass exactly through the dyadic vertices below


@pytest.mark.parametrize("case", ["torus", "octahedron", "box", "cylinder", "two_bodies"])
def test_culled_grid_equals_unculled_brute_force(case, monkeypatch):
    if case == "torus":
        mesh = trimesh.creation.torus(0.03, 0.012, major_sections=14, minor_sections=8)
    elif case == "octahedron":  # rays exactly through vertices and edges (ties)
        mesh = _octahedron(10 * CELL)
    elif case == "box":  # faces edge-on to the rays, edges and corners on grid columns
        mesh = trimesh.creation.box((16 * CELL, 10 * CELL, 12 * CELL))
    elif case == "cylinder":  # vertical walls seen edge-on by the rays
        mesh = trimesh.creation.cylinder(0.02, 0.04, sections=12)
    else:
        box = trimesh.creation.box((0.02, 0.02, 0.02),
                                   trimesh.transformations.translation_matrix([0.03, 0.01, 0]))
        mesh = trimesh.util.concatenate([trimesh.creation.icosphere(1, radius=0.015), box])
    leaf_pairs = []
    real = M._pair_dist2
    monkeypatch.setattr(M, "_pair_dist2",
                        lambda c, o, *a: leaf_pairs.append(len(a[1])) or real(c, o, *a))
    grid = mesh_sdf_grid(mesh, thickness=4 * CELL, margin=2 * CELL, cache_dir=False,
                         dtype=torch.float64)
    dist, wind = _brute(mesh, grid)
    got = grid.values.numpy()
    assert np.abs(np.abs(got) - dist).max() < 1e-7  # float32 rounding only
    clear = dist > 1e-6  # on-surface nodes have no sign to check
    assert clear.sum() > 0.8 * clear.size
    assert np.all((got[clear] < 0) == (np.abs(wind[clear]) > 0.5))
    assert np.allclose(wind[clear], np.round(wind[clear]), atol=1e-6)
    if len(mesh.faces) > 40:  # the culling was real: far fewer (leaf box, triangle) pairs
        assert leaf_pairs[-1] < 0.5 * (got.size / M._LEAF**3) * len(mesh.faces)


def test_inverted_mesh_gives_the_same_grid():
    mesh = trimesh.creation.icosphere(1, radius=0.02)
    a = mesh_sdf_grid(mesh, 0.01, cache_dir=False).values
    mesh.invert()
    b = mesh_sdf_grid(mesh, 0.01, cache_dir=False).values
    assert (a - b).abs().max() < 1e-8 and ((a < -1e-8) == (b < -1e-8)).all() and (a < 0).sum() > 50


# --- cache ---------------------------------------------------------------------------------------

def test_cache_round_trip_keys_and_corrupt_file(tmp_path, monkeypatch):
    mesh = trimesh.creation.icosphere(1, radius=0.02)
    first = mesh_sdf_grid(mesh, 0.01, cache_dir=tmp_path)
    files = list(tmp_path.glob("*.npz"))
    assert [f.name for f in files] == [sdf_cache_key(mesh, 0.0025, 0.0075, 0.01) + ".npz"]
    real = M._compute_values

    def refuse(*args, **kwargs):
        raise AssertionError("should have been read from the cache")

    monkeypatch.setattr(M, "_compute_values", refuse)
    again = mesh_sdf_grid(mesh, 0.01, cache_dir=tmp_path, dtype=torch.float64, name="again")
    assert again.name == "again" and again.values.dtype == torch.float64
    assert torch.equal(again.values.float(), first.values)
    assert torch.equal(again.origin.float(), first.origin)
    with pytest.raises(AssertionError):  # another cell is another key
        mesh_sdf_grid(mesh, 0.01, cell=0.002, cache_dir=tmp_path)
    moved = mesh.copy()
    moved.vertices[0] += 1e-9
    assert sdf_cache_key(moved, 0.0025, 0.0075, 0.01) != sdf_cache_key(mesh, 0.0025, 0.0075, 0.01)
    assert sdf_cache_key(mesh, 0.0025, 0.0075, 0.02) != sdf_cache_key(mesh, 0.0025, 0.0075, 0.01)
    monkeypatch.setattr(M, "_compute_values", real)
    files[0].write_bytes(b"PK\x03\x04 not really a zip file")
    with pytest.warns(UserWarning, match="unreadable"):
        rebuilt = mesh_sdf_grid(mesh, 0.01, cache_dir=tmp_path)
    assert torch.equal(rebuilt.values, first.values)
    np.savez(files[0], values=np.array([None], dtype=object), origin=np.zeros(3), cell=0.0025,
             thickness=0.01)
    with pytest.warns(UserWarning, match="unreadable"):  # a pickled array is never unpickled
        mesh_sdf_grid(mesh, 0.01, cache_dir=tmp_path)
    with np.load(files[0], allow_pickle=False) as z:  # rewritten, valid again
        assert np.array_equal(z["values"], first.values.numpy())
    assert not list(tmp_path.glob("*.tmp"))  # atomic writes leave no temporaries


def test_cache_folder_from_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("LIQUIDTWIN_CACHE", str(tmp_path))
    mesh = _octahedron(0.02)
    mesh_sdf_grid(mesh, 0.02)
    assert len(list((tmp_path / "sdf").glob("*.npz"))) == 1


# --- errors --------------------------------------------------------------------------------------

def test_clear_errors_for_bad_meshes_and_requests():
    sphere = trimesh.creation.icosphere(1, radius=0.02)
    holed = trimesh.Trimesh(sphere.vertices, sphere.faces[1:], process=False)
    with pytest.raises(ValueError, match=r"not watertight \(3 open edges"):
        mesh_sdf_grid(holed, 0.01, cache_dir=False)
    flipped = sphere.copy()
    flipped.faces[0] = flipped.faces[0, ::-1]
    with pytest.raises(ValueError, match="consistently oriented"):
        mesh_sdf_grid(flipped, 0.01, cache_dir=False)
    v = sphere.vertices.copy()
    v[5] = np.nan
    with pytest.raises(ValueError, match="NaN or inf"):
        mesh_sdf_grid(trimesh.Trimesh(v, sphere.faces, process=False), 0.01, cache_dir=False)
    for bad in (0.0, -0.003, float("nan")):
        with pytest.raises(ValueError, match="wall thickness must be a positive length"):
            mesh_sdf_grid(sphere, bad, cache_dir=False)
    with pytest.raises(TypeError, match="expected a trimesh.Trimesh, got Scene"):
        mesh_sdf_grid(trimesh.Scene(sphere), 0.01, cache_dir=False)
    with pytest.raises(ValueError, match="margin must be a non-negative"):
        mesh_sdf_grid(sphere, 0.01, margin=-0.001, cache_dir=False)
    with pytest.raises(ValueError, match="no grid node lies inside"):
        mesh_sdf_grid(trimesh.creation.box((2e-4, 2e-4, 2e-4)), 0.01, cell=0.001, cache_dir=False)


def test_node_budget_error_suggests_a_cell_that_fits():
    mesh = trimesh.creation.box((1.0, 0.5, 0.8))
    with pytest.raises(ValueError, match="max_nodes") as err:
        mesh_sdf_grid(mesh, 0.003, cache_dir=False)  # 0.75 mm over a metre: ~1e9 nodes
    cell = float(str(err.value).split("pass cell=")[1].split(" ")[0])
    assert 0.0036 < cell < 0.0045  # ≈ (0.4 m³ / 8e6 nodes)^(1/3) = 3.7 mm
    _, shape = M._layout(mesh.bounds, cell, 3 * cell, M.DEFAULT_MAX_NODES, "box")
    assert math.prod(shape) <= M.DEFAULT_MAX_NODES


def test_coarse_cell_warns():
    with pytest.warns(UserWarning, match="coarser than a quarter"):
        mesh_sdf_grid(_octahedron(0.02), 0.004, cell=0.002, cache_dir=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh_sdf_grid(_octahedron(0.02), 0.008, cell=0.002, cache_dir=False)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_build_matches_cpu():
    mesh = _cup_mesh(0.02, 0.03, 0.002, 24)
    cpu = mesh_sdf_grid(mesh, 0.004, cache_dir=False)
    gpu = mesh_sdf_grid(mesh, 0.004, cache_dir=False, device="cuda")
    assert gpu.values.is_cuda
    assert torch.allclose(gpu.values.cpu(), cpu.values, atol=1e-6)
