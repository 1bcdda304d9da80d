"""Cameras: projection vs OpenCV, occlusion vs brute-force segment sampling of analytic SDFs,
coverage/mask vs a hand-worked image and a per-particle loop, splats vs a dense formula and
finite differences, IOU by hand, and the errors bad input gets."""

import json
import math

import cv2
import numpy as np
import pytest
import torch

from liquidtwin.camera import (Camera, coverage, disc_stencil, in_view, iou, model_mask,
                               segment_blocked, splat, visible)
from liquidtwin.camera import render as _render
from liquidtwin.camera.pinhole import matrix_to_quat
from liquidtwin.scenes import shapes
from liquidtwin.sim import fused, quat_to_matrix

IDENTITY = torch.tensor([[0.0, 0, 0, 0, 0, 0, 1]])


def _random_camera(rng, distortion=None) -> Camera:
    eye = rng.uniform(-1, 1, 3) * np.array([1.0, 0.5, 1.0]) + np.array([0, 0.6, 0])
    target = rng.uniform(-0.1, 0.1, 3)
    return Camera.look_at(eye, target, width=640, height=480, fx=rng.uniform(300, 700),
                          fy=rng.uniform(300, 700),
                          cx=rng.uniform(280, 360), cy=rng.uniform(200, 280), distortion=distortion)


def _cv2_project(cam: Camera, x: np.ndarray) -> np.ndarray:
    R = quat_to_matrix(cam.pose[3:].double()).numpy()
    t = cam.pose[:3].double().numpy()
    rvec, _ = cv2.Rodrigues(R.T)  # world → camera
    tvec = -R.T @ t
    uv, _ = cv2.projectPoints(x.reshape(-1, 1, 3), rvec, tvec, cam.K.numpy(),
                              cam.distortion.numpy())
    return uv.reshape(-1, 2)


# ---------------------------------------------------------------- projection

@pytest.mark.parametrize("distorted", [False, True])
def test_project_matches_opencv(distorted):
    rng = np.random.default_rng(1 + distorted)
    for _ in range(5):
        d = rng.uniform(-0.2, 0.2, 5) * np.array([1, 0.5, 0.02, 0.02, 0.2]) if distorted else None
        cam = _random_camera(rng, d)
        x = rng.uniform(-0.3, 0.3, (200, 3))
        uv, depth = cam.project(torch.as_tensor(x))
        assert uv.dtype == torch.float64
        assert np.abs(uv.numpy() - _cv2_project(cam, x)).max() < 1e-4
        ref_depth = cam.world_to_camera(torch.as_tensor(x))[:, 2]
        assert torch.allclose(depth, ref_depth)
        assert bool((depth > 0).all())  # all points lie in front of these cameras


def test_look_at_geometry():
    cam = Camera.look_at((0.3, 0.4, 0.5), (0.0, 0.1, 0.0), width=64, height=48, fov_y_deg=60)
    uv, depth = cam.project(torch.tensor([[0.0, 0.1, 0.0], [0.0, 0.3, 0.0]], dtype=torch.float64))
    assert torch.allclose(uv[0], torch.tensor([31.5, 23.5], dtype=torch.float64), atol=1e-9)
    assert math.isclose(float(depth[0]), math.sqrt(0.09 + 0.09 + 0.25), rel_tol=1e-9)
    assert float(uv[1, 1]) < 23.5  # a point above the target is higher in the image (v down)
    assert math.isclose(cam.fy, 24 / math.tan(math.radians(30)), rel_tol=1e-12) and cam.fx == cam.fy
    R = cam.rotation.double()
    assert torch.allclose(R.T @ R, torch.eye(3, dtype=torch.float64), atol=1e-6)
    assert float(torch.det(R)) > 0
    # looking straight down needs another up vector
    down = Camera.look_at((0, 1, 0), (0, 0, 0), up=(0, 0, -1), width=10, height=10, fx=10)
    uv, _ = down.project(torch.tensor([[0.1, 0.0, 0.0], [0.0, 0.0, -0.1]]))
    assert float(uv[0, 0]) > 4.5 and abs(float(uv[1, 0]) - 4.5) < 1e-5 and float(uv[1, 1]) < 4.5


def test_matrix_to_quat_round_trip():
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = torch.as_tensor(rng.normal(size=4))
        q = q / q.norm()
        R = quat_to_matrix(q)
        assert torch.allclose(quat_to_matrix(matrix_to_quat(R)), R, atol=1e-12)


def test_project_gradcheck():
    cam = Camera.look_at((0.4, 0.3, 0.5), (0, 0.05, 0), width=64, height=48, fx=50.0, fy=55.0,
                         distortion=(0.1, -0.05, 0.01, -0.02, 0.01))
    x = torch.tensor([[0.01, 0.02, 0.03], [-0.05, 0.1, 0.0], [0.1, -0.02, 0.05]],
                     dtype=torch.float64, requires_grad=True)
    pose = cam.pose.double().clone().requires_grad_()

    def f(x, pose):
        uv, depth = cam.with_pose(pose).project(x)
        return uv, depth

    assert torch.autograd.gradcheck(f, (x, pose), eps=1e-6, atol=1e-6)


def test_foxglove_fields_round_trip():
    cam = Camera.look_at((0.4, 0.3, 0.5), (0, 0.05, 0), width=640, height=480, fx=500.0, fy=510.0,
                         cx=320.5, cy=240.25, distortion=(0.1, -0.2, 0.001, 0.002, 0.03),
                         name="thermal")
    f = cam.to_foxglove_fields()
    assert f["K"] == [500.0, 0.0, 320.5, 0.0, 510.0, 240.25, 0.0, 0.0, 1.0]
    assert f["P"] == [500.0, 0.0, 320.5, 0.0, 0.0, 510.0, 240.25, 0.0, 0.0, 0.0, 1.0, 0.0]
    assert f["R"] == [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
    assert f["distortion_model"] == "plumb_bob" and (f["width"], f["height"]) == (640, 480)
    assert np.allclose(f["D"], [0.1, -0.2, 0.001, 0.002, 0.03])
    back = Camera.from_calibration(f["K"], f["D"], f["width"], f["height"], cam.pose, f["frame_id"])
    x = torch.rand(20, 3, dtype=torch.float64) * 0.1
    assert torch.allclose(back.project(x)[0], cam.project(x)[0])
    assert torch.equal(back.K, cam.K)
    no_d = Camera.from_calibration(np.array(f["K"]).reshape(3, 3), [], 640, 480, cam.pose)
    assert torch.equal(no_d.distortion, torch.zeros(5, dtype=torch.float64))


def test_camera_bad_input():
    pose = torch.tensor([0.0, 0, 0, 0, 0, 0, 1])
    ok = dict(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0, pose=pose)
    Camera(**ok)
    nan = float("nan")
    bad = [dict(width=0), dict(height=-3), dict(width=10.5), dict(fx=0.0), dict(fy=-1.0),
           dict(cx=nan),
           dict(pose=torch.tensor([0.0, 0, 0, 0, 0, 0, 2])),
           dict(pose=torch.tensor([0.0, 0, nan, 0, 0, 0, 1])), dict(pose=torch.zeros(6)),
           dict(distortion=torch.zeros(3)), dict(distortion=[0, 0, 0, 0, float("inf")])]
    for b in bad:
        with pytest.raises(ValueError):
            Camera(**{**ok, **b})
    cam = Camera(**ok)
    for x in (torch.zeros(5, 2), torch.zeros(3), torch.tensor([[0.0, float("nan"), 1.0]])):
        with pytest.raises(ValueError):
            cam.project(x)
    with pytest.raises(ValueError, match="parallel"):
        Camera.look_at((0, 1, 0), (0, 0, 0), width=10, height=10, fx=10)
    with pytest.raises(ValueError, match="coincide"):
        Camera.look_at((0, 1, 0), (0, 1, 0), width=10, height=10, fx=10)
    with pytest.raises(ValueError, match="exactly one"):
        Camera.look_at((0, 1, 1), (0, 0, 0), width=10, height=10)
    with pytest.raises(ValueError, match="exactly one"):
        Camera.look_at((0, 1, 1), (0, 0, 0), width=10, height=10, fov_y_deg=60, fy=5.0)
    with pytest.raises(ValueError, match="fov_y_deg"):
        Camera.look_at((0, 1, 1), (0, 0, 0), width=10, height=10, fov_y_deg=180)
    with pytest.raises(ValueError, match="skew"):
        Camera.from_calibration([50, 1, 32, 0, 50, 24, 0, 0, 1], [], 64, 48, pose)


# ---------------------------------------------------------------- occlusion

CUP = dict(radius=0.04, height=0.10, wall=0.003)


@pytest.fixture(scope="module")
def cup():
    return shapes.cup_grid(**CUP)


def _cup_interior(n_side=5):
    """Particles filling the cup cavity, including ones touching the wall and the bottom."""
    r_in, wall = CUP["radius"], CUP["wall"]
    pts = []
    for y in np.linspace(wall + 0.0008, 0.08, n_side):
        for r in (0.0, 0.02, r_in - 0.0008):
            for a in np.linspace(0, 2 * np.pi, 8, endpoint=False):
                pts.append((r * np.cos(a), y, r * np.sin(a)))
    return torch.tensor(pts, dtype=torch.float32)


def test_particles_in_cup_hidden_from_side_visible_from_above(cup):
    x = _cup_interior()
    for eye in [(0.5, 0.05, 0.0), (-0.3, 0.09, 0.3), (0.0, 0.02, -0.4)]:  # side, below the rim
        cam = Camera.look_at(eye, (0, 0.05, 0), width=320, height=240, fov_y_deg=60)
        assert bool(in_view(cam, x).all())
        assert not bool(visible(cam, x, [cup], IDENTITY).any()), eye
    above = Camera.look_at((0.0, 0.6, 0.0), (0, 0.0, 0), up=(0, 0, -1), width=320, height=240,
                           fov_y_deg=60)
    assert bool(visible(above, x, [cup], IDENTITY).all())
    # a stream above the cup and one beside it are seen from the side
    stream = torch.tensor([[0.0, y, 0.0] for y in np.linspace(0.11, 0.2, 10)]
                          + [[0.0, y, 0.12] for y in np.linspace(0.0, 0.2, 10)],
                          dtype=torch.float32)
    side = Camera.look_at((0.5, 0.1, 0.0), (0, 0.1, 0), width=320, height=240, fov_y_deg=60)
    assert bool(visible(side, stream, [cup], IDENTITY).all())
    # the cup moved out of the way: the same interior particles are visible
    away = torch.tensor([[1.0, 0, 0, 0, 0, 0, 1]])
    side = Camera.look_at((0.5, 0.05, 0.0), (0, 0.05, 0), width=320, height=240, fov_y_deg=60)
    assert bool(visible(side, x, [cup], away).all())


def test_particle_slightly_inside_wall_not_self_occluded(cup):
    r_in = CUP["radius"]
    # 0.3 mm into the inner wall surface (what a collision push-out may leave), and on it
    x = torch.tensor([[r_in + 0.0003, 0.05, 0.0], [r_in, 0.05, 0.0],
                      [0.0, CUP["wall"] - 0.0003, 0.0]])
    above = Camera.look_at((0.0, 0.5, 0.0), (0, 0.0, 0), up=(0, 0, -1), width=320, height=240,
                           fov_y_deg=60)
    assert bool(visible(above, x, [cup], IDENTITY).all())
    side = Camera.look_at((0.5, 0.05, 0.0), (0, 0.05, 0), width=320, height=240, fov_y_deg=60)
    assert not bool(visible(side, x, [cup], IDENTITY).any())


@pytest.mark.parametrize("angle_deg", [0, 30, 60, 75, 85])
def test_thin_wall_hides_at_grazing_angles(angle_deg):
    wall = 0.003
    slab = shapes.sample_grid(lambda p: shapes.box(p, (wall / 2, 0.1, 0.1)),
                              (-0.004, -0.104, -0.104), (0.004, 0.104, 0.104), wall / 4, wall,
                              "slab")
    a = math.radians(angle_deg)
    # particles just behind the wall (x < 0), camera in front at angle a from the wall normal;
    # every segment meets the wall plane within the slab (|z| < 0.1 there, even at 85°)
    behind = torch.tensor([[-wall / 2 - d, y, z] for d in (0.0002, 0.001, 0.01)
                           for y in (-0.02, 0.0, 0.03) for z in (-0.08, -0.05)],
                          dtype=torch.float32)
    front = behind * torch.tensor([-1.0, 1, 1])
    cam_pos = torch.tensor([0.3 * math.cos(a), 0.0, 0.3 * math.sin(a)])
    assert bool(segment_blocked(behind, cam_pos, [slab], IDENTITY).all()), angle_deg
    assert not bool(segment_blocked(front, cam_pos, [slab], IDENTITY).any()), angle_deg


SHAPES = {"cup": (shapes.cup, shapes.cup_grid, CUP),
          "bowl": (shapes.bowl, shapes.bowl_grid, dict(radius=0.08, wall=0.003))}


@pytest.mark.parametrize("backend", ["auto", "torch"])
@pytest.mark.parametrize("shape", ["cup", "bowl"])
def test_occlusion_matches_brute_force_sampling(shape, backend):
    """Random particles (inside and well outside the SDF grid box) and camera positions around a
    tilted, shifted container; the reference samples the analytic SDF every ≤ 0.1 mm along each
    segment. (The bowl's grid box has corners far from the bowl, where a plain grid lookup
    over-estimates the distance and a march would step through the wall.)"""
    fn, grid, kw = SHAPES[shape]
    rng = np.random.default_rng(7)
    q = np.array([math.sin(0.15), 0.0, math.sin(0.1), 1.0])
    q /= np.linalg.norm(q)
    pose = np.concatenate([[0.02, 0.01, -0.03], q])
    R = quat_to_matrix(torch.as_tensor(q)).numpy()
    near = rng.uniform([-0.09, -0.01, -0.09], [0.09, 0.11, 0.09], (800, 3))
    far = rng.uniform([-0.2, -0.1, -0.2], [0.2, 0.25, 0.2], (800, 3))
    x_loc = np.concatenate([near[fn(near, **kw) > 0.0005][:250], far[fn(far, **kw) > 0.0005][:150]])
    x = x_loc @ R.T + pose[:3]
    cams = rng.normal(size=(len(x), 3))
    cams = 0.4 * cams / np.linalg.norm(cams, axis=1, keepdims=True) + pose[:3]
    f32 = dict(dtype=torch.float32)
    got = segment_blocked(torch.as_tensor(x, **f32), torch.as_tensor(cams, **f32), [grid(**kw)],
                          torch.as_tensor(pose, **f32)[None], backend=backend).numpy()
    s = np.linspace(0, 1, 6001)[None, :, None]
    deepest = np.concatenate([
        fn((x[i:i + 50, None] + s * (cams - x)[i:i + 50, None] - pose[:3]) @ R, **kw).min(1)
        for i in range(0, len(x), 50)])
    sure_hit, sure_clear = deepest < -0.0012, deepest > 0.0002
    assert sure_hit.sum() > 60 and sure_clear.sum() > 200
    assert got[sure_hit].all() and not got[sure_clear].any()
    # the uncertain band (segments that only clip a rim or brush a surface) is small
    assert (~sure_hit & ~sure_clear).mean() < 0.05


@pytest.mark.skipif(not fused.available(), reason="C++ extension not built")
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_occlusion_march_equals_the_torch_march(dtype):
    """The C++ march (one ray per thread) takes the same samples as the torch loop (rounds of
    batched ops): a cup and a bowl, tilted and shifted, rays from particles in, around and
    far from them to cameras all around."""
    objects = [shapes.cup_grid(**CUP), shapes.bowl_grid(radius=0.08, wall=0.003)]
    q = torch.tensor([math.sin(0.15), 0.0, math.sin(0.1), 1.0], dtype=torch.float64)
    poses = torch.stack([torch.cat([torch.tensor([0.02, 0.01, -0.03], dtype=torch.float64), q / q.norm()]),
                         torch.tensor([0.0, -0.05, 0.12, 0.0, 0.0, 0.0, 1.0], dtype=torch.float64)]).to(dtype)
    g = torch.Generator().manual_seed(11)
    x = (torch.rand(3000, 3, generator=g, dtype=torch.float64) * torch.tensor([0.3, 0.25, 0.4])
         - torch.tensor([0.15, 0.08, 0.12])).to(dtype)
    cams = torch.randn(3000, 3, generator=g, dtype=torch.float64)
    cams = (0.5 * cams / cams.norm(dim=1, keepdim=True)).to(dtype)
    native = segment_blocked(x, cams, objects, poses)
    ref = segment_blocked(x, cams, objects, poses, backend="torch")
    assert 300 < int(ref.sum()) < 2700
    assert torch.equal(native, ref), int((native != ref).sum())
    one_camera = torch.tensor([0.1, 0.3, 0.4], dtype=dtype)
    assert torch.equal(segment_blocked(x, one_camera, objects, poses),
                       segment_blocked(x, one_camera, objects, poses, backend="torch"))
    with pytest.raises(ValueError, match="backend"):
        segment_blocked(x, one_camera, objects, poses, backend="cuda")
    # more objects than the march keeps on its stack (8): the same samples from the heap
    many = objects * 5
    shifts = torch.arange(len(many), dtype=torch.float64)[:, None] * torch.tensor([0.03, -0.02, 0.025])
    poses_many = torch.cat([poses.double().repeat(5, 1)[:, :3] + shifts, poses.double().repeat(5, 1)[:, 3:]], 1).to(dtype)
    ref = segment_blocked(x[:1000], cams[:1000], many, poses_many, backend="torch")
    assert 100 < int(ref.sum()) < 900
    assert torch.equal(segment_blocked(x[:1000], cams[:1000], many, poses_many), ref)


def test_visible_front_and_image_bounds():
    cam = Camera.look_at((0, 0, 1.0), (0, 0, 0), width=100, height=80, fx=100.0)
    x = torch.tensor([[0.0, 0, 0], [0.0, 0, 2.0], [0.0, 0, 1.0], [0.6, 0, 0], [0.0, 0.45, 0],
                      [0.49, 0, 0]])
    # behind the camera, at its centre, outside the image (x, y), just inside
    assert visible(cam, x).tolist() == [True, False, False, False, False, True]
    assert visible(cam, x, margin_px=15).tolist() == [True, False, False, True, True, True]
    slab = shapes.sample_grid(lambda p: shapes.box(p, (0.1, 0.1, 0.0015)), (-0.11, -0.11, -0.003),
                              (0.11, 0.11, 0.003), 0.00075, 0.003, "slab")
    pose = torch.tensor([[0.0, 0, 0.5, 0, 0, 0, 1]])
    # the last one's segment passes beside the slab (it meets z = 0.5 at x = 0.245)
    assert visible(cam, x, [slab], pose).tolist() == [False, False, False, False, False, True]
    assert visible(cam, x, [slab], torch.tensor([[5.0, 0, 0.5, 0, 0, 0, 1]])).tolist()[0]


def test_occlusion_bad_input(cup):
    cam = Camera.look_at((0, 0, 1.0), (0, 0, 0), width=100, height=80, fx=100.0)
    x = torch.zeros(4, 3)
    with pytest.raises(ValueError):
        visible(cam, torch.zeros(4, 2), [cup], IDENTITY)
    with pytest.raises(ValueError):
        visible(cam, torch.full((4, 3), float("nan")))
    with pytest.raises(ValueError, match="poses"):
        visible(cam, x, [cup])
    with pytest.raises(ValueError):
        visible(cam, x, [cup], torch.zeros(2, 7))
    with pytest.raises(ValueError):
        segment_blocked(x, torch.zeros(3, 3), [cup], IDENTITY)


# ---------------------------------------------------------------- coverage and mask

HAND_COVERAGE = """
000000000111
000110000011
001221000001
012222100000
001221000000
000110000000
100000000000
000000000000
000000000000
000000000000
000000000000
000000000000
"""


def test_coverage_hand_case():
    # A (3, 3); B (4.4, 3.2) snaps to (4, 3); C (11.3, 0.4) → (11, 0), clipped by the border;
    # D invisible; E (-2.4, 6) → (-2, 6): only its rightmost pixel (6, 0) falls inside.
    uv = torch.tensor([[3.0, 3.0], [4.4, 3.2], [11.3, 0.4], [6.0, 8.0], [-2.4, 6.0]])
    vis = torch.tensor([True, True, True, False, True])
    want = torch.tensor([[int(c) for c in row] for row in HAND_COVERAGE.split()], dtype=torch.int32)
    got = coverage(uv, vis, 12, 12, radius_px=2)
    assert got.dtype == torch.int32 and torch.equal(got, want)
    assert torch.equal(model_mask(uv, vis, 12, 12, radius_px=2), want > 0)
    assert int(disc_stencil(2).sum()) == 13


@pytest.mark.parametrize("radius", [0, 1.5, 2.5, 5, 12])
def test_coverage_and_mask_match_per_particle_loop(radius):
    rng = np.random.default_rng(11)
    H, W = 37, 53
    uv = rng.uniform([-8, -8], [W + 8, H + 8], (120, 2))
    uv[:10] = np.round(uv[:10]) + 0.5  # exact half-pixel ties round up
    vis = rng.uniform(size=120) < 0.8
    ref = np.zeros((H, W), np.int32)
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    for (u, v), s in zip(uv, vis):
        if s:
            ref += (jj - math.floor(u + 0.5)) ** 2 + (ii - math.floor(v + 0.5)) ** 2 <= radius ** 2
    uvt, vist = torch.as_tensor(uv, dtype=torch.float32), torch.as_tensor(vis)
    cov = coverage(uvt, vist, H, W, radius)
    assert np.array_equal(cov.numpy(), ref)
    assert np.array_equal(model_mask(uvt, vist, H, W, radius).numpy(), ref > 0)
    # the conv2d path used on GPUs gives the same integers
    R = int(math.floor(radius))
    t = _render._coverage_torch(_render._counts(uvt[vist], H, W, R), disc_stencil(radius))
    assert np.array_equal(torch.round(t).numpy().astype(np.int32), ref)


def test_sphere_coverage_matches_per_particle_loop():
    # Each particle drawn as its own projected sphere: radius fx·r/depth, half-pixel rounded.
    rng = np.random.default_rng(5)
    H, W, fx, r_m = 40, 60, 300.0, 0.004
    uv = torch.as_tensor(rng.uniform([-5, -5], [W + 5, H + 5], (90, 2)))
    depth = torch.as_tensor(rng.uniform(0.15, 2.0, 90))
    vis = torch.as_tensor(rng.uniform(size=90) < 0.85)
    r_px = _render.sphere_radius_px(fx, depth, r_m, min_px=1.0)
    raw = np.clip(fx * r_m / depth.numpy(), 1.0, 40.0)
    assert np.allclose(r_px.numpy(), np.round(raw * 2) / 2)
    assert len(torch.unique(r_px)) > 3                     # several radius groups exercised
    ref = np.zeros((H, W), np.int32)
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    for (u, v), r, s in zip(uv.numpy(), r_px.numpy(), vis.numpy()):
        if s:
            ref += (jj - math.floor(u + 0.5)) ** 2 + (ii - math.floor(v + 0.5)) ** 2 <= r ** 2
    assert np.array_equal(_render.sphere_coverage(uv, r_px, vis, H, W).numpy(), ref)


def test_mask_dense_particles_and_invisible_not_drawn():
    rng = np.random.default_rng(5)
    uv = torch.as_tensor(rng.uniform(0, 64, (5000, 2)), dtype=torch.float32)
    vis = torch.zeros(5000, dtype=torch.bool)
    assert not bool(model_mask(uv, vis, 48, 64).any()) and int(coverage(uv, vis, 48, 64).sum()) == 0
    vis[::2] = True
    c = coverage(uv, vis, 48, 64)
    assert torch.equal(model_mask(uv, vis, 48, 64), c > 0)
    one_by_one = sum(int(coverage(uv[i:i + 1], None, 48, 64).sum()) for i in range(0, 5000, 2))
    assert int(c.sum()) == one_by_one
    # invisible particles may carry garbage coordinates (e.g. behind the camera)
    uv2 = torch.cat([uv[:4], torch.tensor([[float("nan"), float("inf")]])])
    vis2 = torch.tensor([True, True, True, True, False])
    assert torch.equal(coverage(uv2, vis2, 48, 64), coverage(uv[:4], None, 48, 64))


def test_render_bad_input():
    uv = torch.zeros(3, 2)
    vis = torch.ones(3, dtype=torch.bool)
    for f in (coverage, model_mask, splat):
        for args in [(torch.zeros(3, 3), vis, 8, 8), (uv, vis, 0, 8), (uv, vis, 8, -1),
                     (uv, vis, 8.5, 8),
                     (uv, torch.ones(2, dtype=torch.bool), 8, 8), (uv, torch.ones(3), 8, 8),
                     (torch.tensor([[float("nan"), 0.0]]), None, 8, 8)]:
            with pytest.raises(ValueError):
                f(*args)
    with pytest.raises(ValueError):
        coverage(uv, vis, 8, 8, radius_px=-1)
    with pytest.raises(ValueError):
        splat(uv, vis, 8, 8, sigma_px=0)


# ---------------------------------------------------------------- splat

def _dense_splat(uv, H, W, sigma, gain, bias, trunc=4.0):
    c = math.exp(-0.5 * trunc * trunc)

    def g(d):
        return np.clip((np.exp(-d * d / (2 * sigma * sigma)) - c) / (1 - c), 0, None)
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    acc = sum(g(jj - u) * g(ii - v) for u, v in uv)
    return 1 / (1 + np.exp(-(gain * acc + bias)))


def test_splat_matches_dense_formula_and_range():
    rng = np.random.default_rng(2)
    uv = rng.uniform([-10, -10], [50, 40], (40, 2))
    out = splat(torch.as_tensor(uv), None, 30, 40, sigma_px=1.7, gain=6.0, bias=-3.0)
    assert out.shape == (30, 40) and out.dtype == torch.float64
    assert np.abs(out.numpy() - _dense_splat(uv, 30, 40, 1.7, 6.0, -3.0)).max() < 1e-12
    assert bool(((out > 0) & (out < 1)).all())
    one = splat(torch.tensor([[5.0, 4.0]]), None, 10, 10, sigma_px=1.0, gain=10.0, bias=-5.0)
    assert math.isclose(float(one[4, 5]), 1 / (1 + math.exp(-5.0)), rel_tol=1e-6)


def test_splat_far_and_invisible_particles_do_not_touch_the_image():
    uv = torch.tensor([[-20.0, 5.0], [5.0, 60.0], [200.0, -200.0], [3e20, 5.0], [5.0, 5.0]],
                      requires_grad=True)
    vis = torch.tensor([True, True, True, True, False])
    out = splat(uv, vis, 16, 16, sigma_px=2.0, gain=10.0, bias=-4.0)
    assert torch.equal(out, torch.full((16, 16), torch.sigmoid(torch.tensor(-4.0)).item()))
    out.sum().backward()
    assert torch.equal(uv.grad, torch.zeros_like(uv))


def test_splat_gradcheck():
    uv = torch.tensor([[2.3, 3.1], [4.7, 2.2], [0.4, 5.9], [7.2, 1.1]], dtype=torch.float64,
                      requires_grad=True)
    gain = torch.tensor(3.0, dtype=torch.float64, requires_grad=True)
    bias = torch.tensor(-1.5, dtype=torch.float64, requires_grad=True)
    vis = torch.tensor([True, True, True, False])
    assert torch.autograd.gradcheck(lambda u, g, b: splat(u, vis, 7, 9, 1.2, g, b),
                                    (uv, gain, bias), eps=1e-6, atol=1e-7)


def test_splat_gradient_wrt_camera_pose_finite_differences():
    """d(projection loss)/d(camera pose) through project → splat, vs central differences."""
    rng = np.random.default_rng(4)
    x = torch.as_tensor(rng.uniform(-0.05, 0.05, (30, 3)), dtype=torch.float64)
    cam = Camera.look_at((0.3, 0.2, 0.4), (0, 0, 0), width=24, height=18, fx=40.0)
    target = torch.as_tensor(rng.uniform(size=(18, 24)))
    pose = cam.pose.double()

    def loss(p):
        uv, _ = cam.with_pose(p).project(x)
        return (splat(uv, None, 18, 24, sigma_px=1.5, gain=4.0, bias=-2.0) - target).abs().sum()

    p = pose.clone().requires_grad_()
    loss(p).backward()
    h = 1e-6
    for k in range(7):
        e = torch.zeros(7, dtype=torch.float64)
        e[k] = h
        fd = (loss(pose + e) - loss(pose - e)) / (2 * h)
        assert abs(float(fd) - float(p.grad[k])) < 1e-5 * max(1.0, abs(float(fd))), k


# ---------------------------------------------------------------- iou

def test_iou_hand_cases():
    a = torch.zeros(4, 5, dtype=torch.bool)
    b = torch.zeros(4, 5, dtype=torch.bool)
    assert iou(a, b) == 1.0  # both empty: perfect agreement
    a[0, :4] = True  # 4 pixels
    assert iou(a, b) == 0.0
    b[0, 2:] = True  # 3 pixels, 2 shared → 2 / 5
    assert iou(a, b) == pytest.approx(0.4)
    assert iou(a, a) == 1.0
    with pytest.raises(ValueError):
        iou(a, b[:3])
    with pytest.raises(ValueError):
        iou(a.int(), b)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_matches_cpu():
    rng = np.random.default_rng(8)
    uv = torch.as_tensor(rng.uniform(-10, 650, (8000, 2)), dtype=torch.float32)
    vis = torch.as_tensor(rng.uniform(size=8000) < 0.9)
    cov = coverage(uv, vis, 480, 640)
    assert torch.equal(coverage(uv.cuda(), vis.cuda(), 480, 640).cpu(), cov)
    assert torch.equal(model_mask(uv.cuda(), vis.cuda(), 480, 640).cpu(), cov > 0)
    s = splat(uv, vis, 480, 640)
    assert torch.allclose(splat(uv.cuda(), vis.cuda(), 480, 640).cpu(), s, atol=1e-5)
    cup = shapes.cup_grid()
    x = torch.as_tensor(rng.uniform([-0.05, 0, -0.05], [0.05, 0.12, 0.05], (2000, 3)),
                        dtype=torch.float32)
    cam = Camera.look_at((0.4, 0.15, 0.2), (0, 0.05, 0), width=640, height=480, fov_y_deg=50)
    v = visible(cam, x, [cup], IDENTITY)
    vc = visible(cam, x.cuda(), [cup.to("cuda")], IDENTITY.cuda())
    assert vc.device.type == "cuda" and (vc.cpu() != v).sum() <= 2


def test_bench_camera_records(tmp_path):
    from liquidtwin import bench
    out = tmp_path / "camera.json"
    bench.main(["--only", "camera", "--threads", "1", "--history", str(tmp_path / "no" / "h.jsonl"),
                "--out", str(out)])
    recs = {r["what"]: r for r in json.loads(out.read_text())}
    assert set(recs) == {"camera_mask", "camera_occlusion", "camera_splat"}
    for r in recs.values():
        assert r["particles"] == 8000 and 0 < r["visible_particles"] < 8000
        assert r["ms"] > 0 and r["peak_mem_bytes"] > 0 and r["commit"] and r["date"]
    assert not (tmp_path / "no").exists()


def test_box_reach_test_agrees_with_dense_sampling():
    """The early exit of the occlusion march: a segment 'reaches' an object's grid box exactly
    when some point along it lies in the (rotated, shifted) box — checked by sampling."""
    from liquidtwin.sim.segments import _frames, _reaches_a_box
    from liquidtwin.sim import SDFGrid

    g = torch.Generator().manual_seed(3)
    values = torch.rand(5, 4, 6, generator=g, dtype=torch.float64) - 0.5
    grid = SDFGrid(values, torch.tensor([-0.02, 0.0, -0.03], dtype=torch.float64), 0.01, 0.003, "box")
    q = torch.tensor([0.3, 0.1, 0.2, 0.2], dtype=torch.float64)
    pose = torch.cat([torch.tensor([0.05, -0.02, 0.01], dtype=torch.float64), q / q.norm()])[None]
    frames = _frames([grid], pose)
    start = torch.rand(400, 3, generator=g, dtype=torch.float64) * 0.12 - 0.06
    d = torch.randn(400, 3, generator=g, dtype=torch.float64)
    d = d / d.norm(dim=1, keepdim=True)
    length = torch.rand(400, generator=g, dtype=torch.float64) * 0.3
    got = _reaches_a_box(start, d, length, frames)
    R, t, lo, hi = frames[0]
    tau = torch.linspace(0, 1, 4001, dtype=torch.float64)
    pts = start[:, None] + (tau[None, :, None] * length[:, None, None]) * d[:, None]
    local = (pts - t) @ R
    inside = ((local >= lo) & (local <= hi)).all(-1).any(-1)
    assert got.sum() > 20 and (~got).sum() > 20
    assert torch.equal(got, inside)
