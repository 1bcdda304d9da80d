"""MAP-filter tracker: the FFT Ψ image against a brute-force pixel sum, hand-made scenes (a
particle jumps one cell toward liquid, never into or through an object, stays put without
liquid or when occluded), the golden pour in the session engine, and a calm, fully seen bowl."""

import math

import numpy as np
import pytest
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb
from rocked_bowl import bowl_session, rock
from liquidtwin.camera import Camera, coverage, visible
from liquidtwin.scenes.shapes import box, sample_grid
from liquidtwin.sim import FluidModel, lattice
from liquidtwin.tracking import MapFilter, Observation, hypothesis_offsets, image_scale, psi_image

CELL = 0.005


def _brute_psi(weights: np.ndarray, uv: np.ndarray, ell: float, cut: float) -> np.ndarray:
    """Σ_j w_j exp(−|j−p|²/ℓ²) over every pixel j with |j−p| ≤ cut (p itself included): (K,)."""
    H, W = weights.shape
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    out = np.zeros(len(uv))
    for k, (u, v) in enumerate(uv):
        r2 = (jj - u) ** 2 + (ii - v) ** 2
        out[k] = np.where(r2 <= cut * cut, weights * np.exp(-r2 / ell**2), 0.0).sum()
    return out


@pytest.mark.parametrize("ell,cut", [(4.0, 12.0), (16.5, 50.0)])     # 50 px > the image: no wrap-around
def test_psi_image_equals_brute_force_pixel_sum(ell, cut):
    rng = np.random.default_rng(1)
    H, W = 30, 41
    weights = (rng.random((H, W)) < 0.2) / (rng.integers(0, 4, (H, W)) + 1.0)
    psi = psi_image(torch.as_tensor(weights), ell, cut).numpy()
    assert psi.shape == (H, W)
    uv = np.stack([rng.integers(0, W, 30), rng.integers(0, H, 30)], 1)
    np.testing.assert_allclose(psi[uv[:, 1], uv[:, 0]], _brute_psi(weights, uv, ell, cut), rtol=1e-9, atol=1e-9)


def _camera():
    return Camera.look_at([0.0, 0.45, 0.25], [0.0, 0.0, 0.0], width=320, height=240, fov_y_deg=45.0)


def _observe(cam, x, mask, objects=(), poses=None):
    model = FluidModel.create(0.011, dt=1 / 60, objects=objects)
    seen = visible(cam, x, margin_px=5.0)
    uv, depth = cam.project(x)
    cov = coverage(uv, seen, cam.height, cam.width, 5.0)
    poses = torch.zeros(0, 7, dtype=x.dtype) if poses is None else poses
    return Observation(cam, mask, x, torch.zeros_like(x), uv, depth, seen, cov, 5.0, model, poses)


def _blob(cam, centre, radius_px=4.0):
    """(H, W) bool disc of observed liquid around the projection of ``centre`` (3,) m."""
    uv, _ = cam.project(torch.tensor([centre], dtype=torch.float64))
    jj, ii = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    u, v = uv[0].tolist()
    return torch.as_tensor((jj - u) ** 2 + (ii - v) ** 2 <= radius_px**2)


def _brute_choice(cam, obs, x0):
    """The argmax over the 27 hypotheses of x0 (3,) of the brute-force Ψ (coverage from obs)."""
    s = image_scale(cam.height, cam.width)
    hyp = x0[None] + hypothesis_offsets(CELL, x0.dtype)
    uv = cam.project(hyp)[0].numpy()
    weights = obs.mask.numpy() / (obs.coverage.numpy() + 1.0)
    psi = _brute_psi(weights, uv, 33.0 * s, 100.0 * s)
    return hyp[int(np.argmax(psi))] - x0, psi


def test_a_particle_beside_liquid_moves_one_cell_toward_it():
    cam = _camera()
    x = torch.zeros(1, 3, dtype=torch.float64)
    obs = _observe(cam, x, _blob(cam, [0.015, 0.0, 0.0]))
    dx = MapFilter(CELL).correct(obs).dx[0]
    ref, psi = _brute_choice(cam, obs, x[0])
    torch.testing.assert_close(dx, ref)
    assert math.isclose(float(dx[0]), CELL) and psi.max() > psi[13] * 1.01     # toward it, a clear winner
    # and its image moves closer to the blob
    uv = cam.project(torch.tensor([[0.0, 0, 0], dx.tolist(), [0.015, 0, 0]], dtype=torch.float64))[0]
    assert float((uv[1] - uv[2]).norm()) < float((uv[0] - uv[2]).norm()) - 1.0


def _wall_scene(x_lo, x_hi):
    """A solid slab x ∈ [x_lo, x_hi] m, |y|, |z| ≤ 3 cm, at the identity pose."""
    half = [(x_hi - x_lo) / 2, 0.03, 0.03]
    centre = [(x_lo + x_hi) / 2, 0.0, 0.0]
    grid = sample_grid(lambda p: box(p, half, centre), [-0.02, -0.04, -0.04], [0.05, 0.04, 0.04], 0.001,
                       min(x_hi - x_lo, 0.01), "slab", dtype=torch.float64)
    return (grid,), torch.tensor([[0, 0, 0, 0, 0, 0, 1.0]], dtype=torch.float64)


@pytest.mark.parametrize("x_lo,x_hi", [(0.003, 0.03), (0.0015, 0.0035)])   # a block; a 2 mm wall in between
def test_hypotheses_in_or_through_an_object_are_never_chosen(x_lo, x_hi):
    cam = _camera()
    x = torch.zeros(1, 3, dtype=torch.float64)
    mask = _blob(cam, [0.015, 0.0, 0.0])
    free = MapFilter(CELL).correct(_observe(cam, x, mask)).dx[0]
    assert math.isclose(float(free[0]), CELL)                  # without the object the +x side wins
    objects, poses = _wall_scene(x_lo, x_hi)
    obs = _observe(cam, x, mask, objects, poses)
    dx = MapFilter(CELL).correct(obs).dx[0]
    assert float(dx[0]) <= 0.0, dx
    # independent check: the straight path to the chosen point never enters the slab
    t = np.linspace(0, 1, 200)[:, None]
    path = t * dx.numpy()[None]
    assert (box(path, [(x_hi - x_lo) / 2, 0.03, 0.03], [(x_lo + x_hi) / 2, 0, 0]) >= 0).all()


def _ball():
    ball = torch.as_tensor(lattice([-0.02] * 3, [0.02] * 3, 0.006), dtype=torch.float32)
    return ball[ball.norm(dim=1) < 0.02]


def test_no_liquid_or_liquid_out_of_reach_moves_nothing():
    cam, ball = _camera(), _ball()
    assert MapFilter().correct(_observe(cam, ball, torch.zeros(cam.height, cam.width, dtype=torch.bool))) is None
    far = torch.zeros(cam.height, cam.width, dtype=torch.bool)
    far[:, :20] = True                                     # more than r_c (50 px here) from every particle
    uv = cam.project(ball)[0]
    assert float(uv[:, 0].min()) - 20 > 50 * 1.05
    corr = MapFilter(velocity_share=0.5).correct(_observe(cam, ball, far))
    assert bool((corr.dx == 0).all()) and bool((corr.dv == 0).all())


def test_occluded_particles_are_untouched():
    cam, ball = _camera(), _ball()
    mask = torch.zeros(cam.height, cam.width, dtype=torch.bool)
    uv = cam.project(ball + torch.tensor([0.03, 0.0, 0.0]))[0].round().long()
    for u, v in uv.tolist():
        mask[max(v - 5, 0):v + 6, max(u - 5, 0):u + 6] = True
    obs = _observe(cam, ball, mask)
    hidden = torch.rand(len(ball), generator=torch.Generator().manual_seed(2)) < 0.4
    part = Observation(**{**obs.__dict__, "visible": obs.visible & ~hidden})
    corr = MapFilter(CELL, velocity_share=0.5).correct(part)
    assert bool((corr.dx[hidden] == 0).all()) and bool((corr.dv[hidden] == 0).all())
    moved = corr.dx[~hidden].norm(dim=1) > 0
    assert float(moved.float().mean()) > 0.5                 # most visible ones jump toward the liquid
    assert float(corr.dx[~hidden][moved][:, 0].mean()) > 0
    steps = corr.dx[~hidden].abs()
    assert bool(((steps < 1e-6) | ((steps - CELL).abs() < 1e-6)).all())     # whole cells only
    torch.testing.assert_close(corr.dv, corr.dx * (0.5 * 30))                  # share × dx / camera period


def test_rejects_bad_settings():
    for bad in (dict(cell_m=0.0), dict(cell_m=float("nan")), dict(velocity_share=-1.0), dict(length_px=-2.0)):
        with pytest.raises(ValueError):
            MapFilter(**bad)


# ---------------------------------------------------------------- in the session engine
def test_golden_pour_with_the_map_filter_keeps_its_particles_and_tracks_like_open_loop():
    import test_session_engine as S
    from liquidtwin.recordings import read_recording

    rec = read_recording(S.GOLDEN, images=False)
    open_iou, _, open_ms = S._replay(S._engine(rec, pb.OPEN_LOOP), rec)
    eng = S._engine(rec, pb.MAP_FILTER)
    assert isinstance(eng._tracker, MapFilter)
    map_iou, map_vol, map_ms = S._replay(eng, rec)
    print(f"\nmean IOU over {len(open_iou)} liquid frames: open loop {open_iou.mean():.3f}, MAP {map_iou.mean():.3f}; "
          f"ms/frame open {open_ms.mean():.1f}, MAP {map_ms.mean():.1f}; particles {eng.n_particles}, "
          f"lost {eng.lost_particles}; volume errors {np.round(map_vol, 2)}")
    assert len(map_iou) == len(open_iou) >= 10
    # Measured (module doc of map_filter.py): MAP on par with open loop on this pour; chaotic splashes
    # differ between CPUs, so only "not clearly worse" is asserted.
    assert map_iou.mean() > open_iou.mean() - 0.03
    assert eng.lost_particles <= 0.05 * (eng.n_particles + eng.lost_particles)
    assert map_vol[0] < 1.0 and map_vol[-1] < 2.5 and map_vol.max() < 8.0, map_vol


def test_default_correction_keeps_a_fully_seen_bowl_of_liquid_calm():
    """With a big liquid body in view the MAP jumps must not inject energy: the defaults keep
    every particle in a gently rocked bowl, slow; a full velocity share (dv = dx / camera
    period, the thesis's literal momentum rule) is checked too, so the test tells them apart."""
    eng, mask = bowl_session(pb.MAP_FILTER, {})
    n0 = eng.n_particles
    n, fastest = rock(eng, mask, 40)
    print(f"\ndefaults: {n}/{n0} particles kept, fastest {fastest:.2f} m/s")
    assert n == n0 and fastest < 0.6, (n, n0, fastest)
    # the thesis's literal settings: 5 mm cells, velocity from the jump, plain argmax
    old, mask = bowl_session(pb.MAP_FILTER, {"cell_m": 0.005, "velocity_share": 1.0, "min_gain": 0.0})
    n_old, fastest_old = rock(old, mask, 40)
    print(f"thesis settings: {n_old}/{n0} particles kept, fastest {fastest_old:.2f} m/s")
    assert fastest_old > 1.0 or n_old < n0, (n_old, fastest_old)


def test_near_ties_go_to_the_shortest_move():
    offs = hypothesis_offsets(1.0)
    corner = int(((offs == torch.tensor([1.0, 1.0, 1.0])).all(1)).nonzero())
    face = int(((offs == torch.tensor([1.0, 0.0, 0.0])).all(1)).nonzero())
    score = torch.zeros(3, 27, dtype=torch.float64)
    score[:, corner], score[:, face] = 0.5004, 0.5
    score[1, corner] = 0.51                   # a clear winner
    score[2] = 0.2                            # all equal: stay
    score[2, 5] = -math.inf
    got = MapFilter(min_gain=1e-3).choose(score).tolist()
    assert got == [face, corner, 13]
    assert MapFilter(min_gain=0.0).choose(score).tolist() == [corner, corner, 13]


def test_covered_liquid_pulls_less_than_uncovered_liquid():
    """Ψ's coverage weighting (Φ + 1): two equal blobs either side of a particle tie, so it
    stays; cover one of them with other particles' discs and the particle jumps toward the
    other one — the brute-force argmax agrees."""
    cam = _camera()
    x = torch.zeros(1, 3, dtype=torch.float64)
    left, right = _blob(cam, [-0.015, 0.0, 0.0], 6.0), _blob(cam, [0.015, 0.0, 0.0], 6.0)
    obs = _observe(cam, x, left | right)
    sym = Observation(**{**obs.__dict__, "coverage": torch.zeros_like(obs.coverage)})
    assert float(MapFilter(CELL).correct(sym).dx.abs().max()) == 0.0
    for covered, sign in ((left, 1.0), (right, -1.0)):
        cov = torch.where(covered, 3, 0).to(torch.int32)
        one = Observation(**{**obs.__dict__, "coverage": cov})
        dx = MapFilter(CELL).correct(one).dx[0]
        ref, psi = _brute_choice(cam, one, x[0])
        torch.testing.assert_close(dx, ref)
        assert math.isclose(float(dx[0]), sign * CELL), dx          # toward the uncovered blob


def test_iterations_walk_several_cells_per_observation():
    cam = _camera()
    x = torch.zeros(1, 3, dtype=torch.float64)
    obs = _observe(cam, x, _blob(cam, [0.03, 0.0, 0.0], 8.0))
    one = MapFilter(CELL).correct(obs).dx[0]
    three = MapFilter(CELL, iterations=3).correct(obs).dx[0]
    assert math.isclose(float(one[0]), CELL)
    assert math.isclose(float(three[0]), 3 * CELL), three             # three cells toward the liquid
    with pytest.raises(ValueError):
        MapFilter(iterations=0)
