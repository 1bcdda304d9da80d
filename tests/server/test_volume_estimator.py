"""Model-based volume estimator (SPEC §5): expected masks against pinhole geometry, tilted
surface heights against a voxel count, the likelihood, the histogram filter, learned transitions."""

import math

import numpy as np
import pytest
import torch
from liquidtwin.camera import Camera
from liquidtwin.geometry import cup
from liquidtwin.sim.sdf import quat_from_axis_angle
from liquidtwin.volumes import (U_BINS, LevelTable, VolumeFilter, crossings, default_transition,
                                downsample_mask, estimate_series, expected_masks, learn_transition,
                                load_transition, log_likelihood, pixel_rays, quat_matrix,
                                scaled_transition)

UPRIGHT = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
R = 0.035                                    # straight cup: cavity radius (72-gon), m


@pytest.fixture(scope="module")
def straight():
    return cup(radius=R, bottom_radius=R)


@pytest.fixture(scope="module")
def tapered():
    return cup()


@pytest.fixture(scope="module")
def oblique(tapered):
    """Expected masks of the tapered cup seen obliquely, 0 … capacity in 25 bins."""
    table = LevelTable.create(tapered, np.linspace(0.0, tapered.capacity_ml, 25))
    cam = Camera.look_at([0.12, 0.25, 0.03], [0, 0.03, 0], width=160, height=120, fov_y_deg=35)
    return table, cam, expected_masks(table, UPRIGHT, cam, stride=2)


def test_expected_masks_grow_with_volume_and_stay_in_the_interior(oblique):
    table, _, e = oblique
    assert e.liquid.shape == (25, 60, 80) and e.interior.sum() > 600
    assert not e.liquid[0].any()                              # empty: nothing expected
    assert not (e.liquid & ~e.interior).any()
    for a, b in zip(e.liquid[:-1], e.liquid[1:]):
        assert not (a & ~b).any()                             # nested masks
    n = e.liquid.sum((1, 2))
    assert n[-1] >= 0.95 * e.interior.sum() and (np.diff(n) >= 0).all() and n[-1] > n[5] > 0
    np.testing.assert_allclose(e.heights, table.upright, atol=0)


def test_top_view_liquid_area_is_the_projected_cross_section(straight):
    """From straight above the liquid is a disc (the 72-gon cross-section A) at depth
    z = y_cam − h(v): its image area is A·f²/z² px, whatever the volume (> 0)."""
    y_cam, f = 3.0, 3600.0
    cam = Camera(200, 200, f, f, 99.5, 99.5, torch.tensor(
        [0.0, y_cam, 0.0, *quat_from_axis_angle(torch.tensor([1.0, 0, 0]), torch.tensor(math.pi / 2)).tolist()],
        dtype=torch.float64))
    assert abs(float(cam.rotation[:, 2] @ torch.tensor([0, -1.0, 0], dtype=torch.float64)) - 1) < 1e-9
    vols = np.array([0.0, 20.0, 100.0, 250.0, 400.0])
    table = LevelTable.create(straight, vols)
    e = expected_masks(table, UPRIGHT, cam, stride=1)
    area = straight.capacity_ml * 1e-6 / (straight.rim_height - straight.floor_height)
    px = e.liquid.sum((1, 2))
    want = area * f**2 / (y_cam - e.heights) ** 2
    assert px[0] == 0
    np.testing.assert_allclose(px[1:], want[1:], rtol=0.02)
    assert px[1:].max() / px[1:].min() < 1.1                 # near constant, grows only with 1/z²
    assert e.interior.sum() == pytest.approx(area * f**2 / (y_cam - straight.rim_height) ** 2, rel=0.02)


def test_side_view_liquid_top_matches_the_projected_height(straight):
    """A glass cup seen from the side, camera below the floor: in the centre column the
    highest liquid pixel is the near top edge, v = cy − f (h − y_cam) / (D − r)."""
    D, y_cam, f = 0.4, 0.0, 600.0
    cam = Camera.look_at([0.0, y_cam, D], [0.0, y_cam, 0.0], width=21, height=400, fx=f)
    vols = np.array([50.0, 150.0, 300.0, 400.0])
    table = LevelTable.create(straight, vols)
    e = expected_masks(table, UPRIGHT, cam, stride=1, opaque=False)
    col = e.liquid[:, :, 10]                                  # centre column (u = cx)
    for k, h in enumerate(e.heights):
        rows = np.nonzero(col[k])[0]
        v_top = cam.cy - f * (h - y_cam) / (D - R)
        v_floor = cam.cy - f * (straight.floor_height - y_cam) / (D - R)
        assert abs(rows.min() - v_top) <= 1.0, (k, rows.min(), v_top)
        assert abs(rows.max() - v_floor) <= 1.0
    opaque = expected_masks(table, UPRIGHT, cam, stride=1)    # opaque walls hide it all
    assert not opaque.liquid.any() and not opaque.interior.any()


def test_tilted_surface_height_holds_the_volume(tapered):
    """Heights for a 0.35 rad tilt: the voxel count of cavity points below the world plane."""
    q = quat_from_axis_angle(torch.tensor([0.0, 0, 1]), torch.tensor(0.35)).numpy()
    pose = np.r_[0.1, 0.2, -0.05, q]
    vols = np.array([30.0, 120.0, 250.0])
    h = LevelTable.create(tapered, vols).heights(pose)
    lo, hi = tapered.cavity.bounds
    n = 64
    axes = [lo[i] + (np.arange(n) + 0.5) * (hi[i] - lo[i]) / n for i in range(3)]
    p = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    p = p[tapered.in_cavity(p)]
    world_y = p @ quat_matrix(q)[1] + pose[1]
    cell = np.prod((hi - lo) / n) * 1e6
    got = np.array([(world_y < hk).sum() * cell for hk in h])
    print("\ntilted heights, voxel-counted volumes:", np.round(got, 2), "ml for", vols)
    np.testing.assert_allclose(got, vols, rtol=0.01)          # measured within 0.35 %
    assert not np.allclose(h, LevelTable.create(tapered, vols).upright + pose[1], atol=1e-3)


def test_surface_offset_lowers_the_drawn_surface_but_not_the_thinnest_layer(straight, tapered, oblique):
    """In a straight cup the surface of v lowered by d is the surface of v − A·d (A: the
    cross-section), upright and tilted; volumes in the thinnest layer keep its surface."""
    area_ml_per_m = straight.capacity_ml / (straight.rim_height - straight.floor_height)
    d = 0.004
    vols = np.array([0.0, 40.0, 120.0, 300.0])
    lowered = LevelTable.create(straight, vols, surface_offset=d)
    shifted = np.r_[0.0, vols[1:] - area_ml_per_m * d]        # 40 ml → 24.6 ml, …
    np.testing.assert_allclose(lowered.heights(UPRIGHT)[1:], LevelTable.create(straight, shifted).heights(UPRIGHT)[1:],
                               atol=1e-6)
    q = quat_from_axis_angle(torch.tensor([0.0, 0, 1]), torch.tensor(0.3)).numpy()
    pose = np.r_[0.0, 0.1, 0.0, q]
    np.testing.assert_allclose(lowered.heights(pose), LevelTable.create(straight, vols).heights(pose) - d, atol=1e-9)
    pool = LevelTable.create(straight, vols, min_depth=0.006, surface_offset=d)
    base = LevelTable.create(straight, vols, min_depth=0.006)
    hp, hb = pool.heights(UPRIGHT), base.heights(UPRIGHT)
    assert hp[0] == hb[0]                                     # the thinnest layer stays
    np.testing.assert_allclose(hp[2:], np.maximum(hb[2:] - d, hb[0]), atol=0)
    table, cam, e = oblique                                   # masks: nested, smaller, same interior
    e_low = expected_masks(LevelTable.create(tapered, table.volumes_ml, surface_offset=d), UPRIGHT, cam, stride=2)
    assert (e_low.interior == e.interior).all() and not (e_low.liquid & ~e.liquid).any()
    assert e_low.liquid.sum() < e.liquid.sum()
    with pytest.raises(ValueError, match="surface_offset"):
        LevelTable.create(straight, vols, surface_offset=-1e-3)


@pytest.mark.parametrize("k_true", [3, 12, 20])
def test_likelihood_peaks_at_the_true_volume_with_10_percent_flipped(oblique, k_true):
    _, _, e = oblique
    rng = np.random.default_rng(k_true)
    obs = e.liquid[k_true] ^ (rng.random(e.interior.shape) < 0.1)
    ll = log_likelihood(e.liquid, e.interior, obs)
    assert int(np.argmax(ll)) == k_true
    # the table, written out for one block
    one = np.zeros((2, 1, 1), bool)
    one[1] = True
    np.testing.assert_allclose(log_likelihood(one, np.ones((1, 1), bool), np.ones((1, 1), bool)),
                               np.log([0.2, 0.9]))


def test_downsample_is_the_block_majority():
    m = np.zeros((4, 6), bool)
    m[0, 0:2] = m[1, 0] = True                # 3 of 4 in block (0, 0)
    m[2, 4] = m[3, 5] = True                  # 2 of 4 in block (1, 2): not a majority
    np.testing.assert_array_equal(downsample_mask(m, 2), [[1, 0, 0], [0, 0, 0]])


def test_filter_tracks_a_slowly_rising_volume(tapered, oblique):
    """Truth rises 0 → 300 ml over 40 frames; observations are the expected masks of the true
    (off-bin) volume with 10 % of the blocks flipped; bins 16 ml apart."""
    table, cam, e = oblique
    truth = np.linspace(0.0, 300.0, 40)
    obs_masks = expected_masks(LevelTable.create(tapered, truth + 1e-9), UPRIGHT, cam, stride=2).liquid
    filt = VolumeFilter(table.volumes_ml, default_transition(len(table.volumes_ml)))
    rng = np.random.default_rng(0)
    b, est = filt.initial(), []
    for k, m in enumerate(obs_masks):
        obs = m ^ (rng.random(m.shape) < 0.1)
        b = filt.update(filt.predict(b) if k else b, log_likelihood(e.liquid, e.interior, obs))
        est.append(filt.median(b))
    err = np.abs(np.array(est) - truth)
    rmse = float(np.sqrt(np.mean(err**2)))
    print(f"\nHMM on a rising volume: RMSE {rmse:.1f} ml, max {err.max():.1f} ml (bins 16 ml)")
    assert err.max() <= 16.0 and rmse <= 8.0             # measured 11.1 and 5.0 ml


def test_learn_transition_recovers_a_known_chain():
    T = np.array([[0.7, 0.3, 0.0, 0.0], [0.1, 0.6, 0.3, 0.0], [0.0, 0.1, 0.6, 0.3],
                  [0.0, 0.0, 0.2, 0.8]])
    bins = np.array([0.0, 10.0, 20.0, 30.0])
    rng = np.random.default_rng(1)
    series = []
    for _ in range(40):
        k, s = 0, []
        for _ in range(250):
            s.append(bins[k] + rng.uniform(-4.9, 4.9))        # off-bin volumes, nearest bin k
            k = rng.choice(4, p=T[k])
        series.append(np.array(s))
    learned = learn_transition(series, bins)
    np.testing.assert_allclose(learned, T, atol=0.03)
    np.testing.assert_allclose(learned.sum(1), 1.0)


def test_bad_input_is_refused(tapered):
    with pytest.raises(ValueError, match="holds"):
        LevelTable.create(tapered, [0.0, tapered.capacity_ml + 10])
    with pytest.raises(ValueError, match="increasing"):
        LevelTable.create(tapered, [10.0, 5.0])
    with pytest.raises(ValueError, match="rows must sum"):
        VolumeFilter(np.array([0.0, 1.0]), np.ones((2, 2)))
    with pytest.raises(ValueError, match="pose"):
        LevelTable.create(tapered, [0.0, 5.0]).heights([0.0, np.nan, 0, 0, 0, 0, 1])
    with pytest.raises(ValueError, match="NaN"):
        learn_transition([np.array([1.0, np.nan])], [0.0, 1.0])
    d = default_transition(5)
    np.testing.assert_allclose(d.sum(1), 1.0)
    assert d[2, 3] > d[2, 1] and d[2, 0] < 1e-5


def test_estimate_series_settles_on_a_still_volume(tapered, oblique):
    """Full-resolution masks (blocks of the 200 ml expected mask, 10 % flipped) through
    estimate_series, which downsamples them and recomputes the expected masks per frame."""
    table, cam, _ = oblique
    m = expected_masks(LevelTable.create(tapered, [200.0]), UPRIGHT, cam, stride=2).liquid[0]
    rng = np.random.default_rng(3)
    masks = np.stack([np.kron(m ^ (rng.random(m.shape) < 0.1), np.ones((2, 2), bool))
                      for _ in range(4)])
    med, post = estimate_series(table, cam, np.tile(UPRIGHT, (4, 1)), masks, stride=2)
    assert post.shape == (4, 25) and np.allclose(post.sum(1), 1.0)
    assert abs(med[-1] - 200.0) <= table.volumes_ml[1]
    with pytest.raises(ValueError, match="same T"):
        estimate_series(table, cam, np.tile(UPRIGHT, (3, 1)), masks, stride=2)


def _brute_crossings(o, d, mesh, pose):
    """Reference: every triangle against every ray (no culling), sorted, coincident hits once."""
    Rm = quat_matrix(pose[3:])
    ol, dl = (o - pose[:3]) @ Rm, d @ Rm
    tri = np.asarray(mesh.vertices, float)[np.asarray(mesh.faces)]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = []
    for dd in dl:
        p = np.cross(dd, e2)
        det = (p * e1).sum(-1)
        tv = ol - a
        qv = np.cross(tv, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v, t = (tv * p).sum(-1) / det, (qv * dd).sum(-1) / det, (e2 * qv).sum(-1) / det
        ts = np.sort(t[(np.abs(det) > 1e-18) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)])
        out.append(ts[np.r_[True, np.diff(ts) >= 1e-9]] if len(ts) else ts)
    return out


@pytest.mark.parametrize("eye", [[0.12, 0.25, 0.03], [0.0, 0.03, 0.0]])    # outside; inside the cup
def test_binned_crossings_equal_brute_force(tapered, eye):
    """The central-projection binning finds exactly the crossings of all-pairs Möller–Trumbore,
    for a tilted cup seen from outside and from a camera inside it (triangles behind it)."""
    cam = Camera.look_at(eye, [0.02, 0.0, 0.0], width=64, height=48, fov_y_deg=70)
    q = quat_from_axis_angle(torch.tensor([0.0, 0, 1]), torch.tensor(0.3)).numpy()
    pose = np.r_[0.01, 0.0, 0.0, q]
    o, d, _ = pixel_rays(cam, 2)
    for mesh in (tapered.cavity, tapered.mesh):
        got = crossings(o, d, mesh, pose)
        want = _brute_crossings(o, d, mesh, pose)
        assert sum(len(w) for w in want) > 50
        for g, w in zip(got, want):
            np.testing.assert_allclose(g[np.isfinite(g)], w, rtol=0, atol=1e-12)


def test_shallow_pool_covers_a_fraction_and_the_likelihood_finds_it(straight):
    """Straight cup from above, min depth 4 mm: the pool holds π r² · 4 mm (the 72-gon's
    area); a volume below it is expected as the full pool disc covering v / pool of it, and
    an observed blob of 30 % of the disc (placed anywhere in it) peaks at 0.3 · pool."""
    depth = 0.004
    area = straight.capacity_ml * 1e-6 / (straight.rim_height - straight.floor_height)
    vols = np.linspace(0.0, 40.0, 81)
    table = LevelTable.create(straight, vols, min_depth=depth)
    assert table.pool_ml == pytest.approx(area * depth * 1e6, rel=1e-6)
    np.testing.assert_allclose(table.fractions, np.minimum(vols / table.pool_ml, 1.0))
    cam = Camera.look_at([0.0, 0.5, 0.001], [0.0, 0.0, 0.0], width=120, height=120, fov_y_deg=12)
    e = expected_masks(table, UPRIGHT, cam, stride=2)
    pool = e.liquid[np.searchsorted(vols, table.pool_ml)]
    for k in np.nonzero(vols < table.pool_ml)[0]:
        np.testing.assert_array_equal(e.liquid[k], pool if vols[k] > 0 else e.liquid[k])
    cells = np.argwhere(pool)
    order = np.argsort(cells[:, 1] + 0.3 * cells[:, 0])         # a blob on one side of the disc
    obs = np.zeros_like(pool)
    n = int(round(0.3 * len(cells)))
    obs[tuple(cells[order[:n]].T)] = True
    ll = log_likelihood(e.liquid, e.interior, obs, fractions=e.fractions)
    best = vols[int(np.argmax(ll))]
    print(f"\npool {table.pool_ml:.2f} ml, {len(cells)} blocks; blob of {n}: best {best:.2f} ml")
    assert abs(best - 0.3 * table.pool_ml) <= vols[1]
    flat = log_likelihood(e.liquid, e.interior, obs)              # without: a film over the floor
    assert vols[int(np.argmax(flat))] == 0.0


def test_pooled_transition_fills_unseen_rows_with_the_shared_steps():
    bins = np.arange(10.0)
    series = [np.array([0, 0, 1, 1, 2, 2, 3, 3, 4, 4], float)]        # stay or +1, rows 0..4 only
    T = learn_transition(series, bins, prior=1e-9, pooled=10.0)
    np.testing.assert_allclose(T.sum(1), 1.0)
    for i in range(6, 9):                                             # unseen: the kernel (stay 5, +1 4)
        assert T[i, i] == pytest.approx(5 / 9, abs=1e-6) and T[i, i + 1] == pytest.approx(4 / 9, abs=1e-6)
    assert T[9, 9] == pytest.approx(1.0, abs=1e-6)                    # the top bin cannot rise
    assert T[0, 0] == pytest.approx((1 + 10 * 5 / 9) / 12, abs=1e-6)  # row 0: 1 stay + 1 up + pooled


def test_shipped_transition_scales_to_a_session(tmp_path):
    u, T = load_transition()
    np.testing.assert_allclose(u, U_BINS) and np.testing.assert_allclose(T.sum(1), 1.0)
    bins, Ts = scaled_transition(50.0, 40.0)
    assert bins[-1] <= 40.0 and np.allclose(bins, U_BINS[:len(bins)] * 50.0) and len(bins) == 41
    np.testing.assert_allclose(Ts.sum(1), 1.0)
    assert Ts.min() > 0 and Ts[10, 10] > 0.3                          # it mostly stays
    bins, Ts = scaled_transition(1000.0, 30.0)                        # far smaller than the liquid
    assert bins[-1] == 30.0 and Ts.shape == (21, 21)
    np.savez(tmp_path / "bad.npz", u_bins=np.arange(3.0), transition=np.ones((3, 3)))
    with pytest.raises(ValueError, match="not a volume transition"):
        load_transition(tmp_path / "bad.npz")
    np.savez(tmp_path / "p.npz", u_bins=np.array([{"a": 1}], dtype=object), transition=np.eye(1))
    with pytest.raises(ValueError, match="pickle"):                   # loaded without pickle
        load_transition(tmp_path / "p.npz")


def test_golden_pan_puddle_is_measured(capsys):
    """The golden dump pour leaves a ~20 ml puddle in a 1.7 l pan: a flat-film model expected it
    over the whole floor and read 0 ml; with the pool depth it reads the puddle. Measured with
    MIN_DEPTH_SPACINGS 1.6 (calibrated on other pours): RMSE 3.25 ml over the 36 masks, 27.6 ml
    (the top bin, 1.2 × the 23 ml fill) at the end for 19.9 ml true; with 0.8: 1.98 ml, 21.2 ml."""
    from pathlib import Path
    from liquidtwin.volumes.estimator import main
    golden = Path(__file__).parent / "data" / "golden_pour_dump.mcap"
    main([str(golden)])
    out = capsys.readouterr().out
    last = [ln for ln in out.splitlines() if ln.startswith("t ")][-1].split()
    est, true = float(last[4]), float(last[7])
    rmse = float(out.split("RMSE")[1].split()[0])
    assert true > 15 and est > 10 and abs(est - true) < 9.0 and rmse < 4.0, out


def _moved(mask: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``mask`` moved by (dy, dx) blocks, zero-filled."""
    out = np.zeros_like(mask)
    h, w = mask.shape
    out[max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)] = mask[max(-dy, 0):h - max(dy, 0), max(-dx, 0):w - max(dx, 0)]
    return out


def _brute_placed(template, interior, obs, region, reach):
    """The best log likelihood of ``template`` over every move within ``reach`` that keeps 90 %
    of it on ``region``, by explicit loops (the reference for the FFT placements)."""
    lp = np.log([0.9, 0.1, 0.2, 0.8])
    P, n_obs = interior.sum(), (obs & interior).sum()
    scores = []
    for dy in range(-reach[0], reach[0] + 1):
        for dx in range(-reach[1], reach[1] + 1):
            t = _moved(template, dy, dx)
            if (t & region).sum() < 0.9 * template.sum():
                continue
            n_exp = (t & interior).sum()
            n11 = (t & interior & obs).sum()
            n01, n10 = n_exp - n11, n_obs - n11
            scores.append(n11 * lp[0] + n01 * lp[1] + n10 * lp[2] + (P - n11 - n01 - n10) * lp[3])
    return max(scores)


def test_placed_likelihood_equals_brute_force_moves(oblique):
    """Whole masks moved up to 15 % of the interior's extent (FFT correlations) score as an
    explicit loop over the moves says; with no shift (the default) the likelihood is the
    fixed-place one."""
    _, _, e = oblique
    rng = np.random.default_rng(3)
    obs = _moved(e.liquid[14], 3, -4) ^ (rng.random(e.interior.shape) < 0.1)
    ll = log_likelihood(e.liquid, e.interior, obs, shift=0.15)
    ys, xs = np.nonzero(e.interior)
    reach = (int(0.15 * (np.ptp(ys))), int(0.15 * (np.ptp(xs))))
    for k in (0, 5, 14, 20, 24):
        want = _brute_placed(e.liquid[k], e.interior, obs, e.interior, reach)
        assert ll[k] == pytest.approx(want, rel=1e-12), k
    fixed = log_likelihood(e.liquid, e.interior, obs)             # the default: no moves
    for k in (5, 14):
        assert fixed[k] == pytest.approx(_brute_placed(e.liquid[k], e.interior, obs, e.interior, (0, 0)), rel=1e-12)
    with pytest.raises(ValueError, match="shift"):
        log_likelihood(e.liquid, e.interior, obs, shift=-0.1)


def test_a_sloshing_surface_moved_sideways_still_reads_its_volume(oblique):
    """The liquid of bin 14 seen 3 blocks up and 4 left of where the level plane puts it (a
    sloshing surface), 10 % of the blocks flipped: the likelihood with moves (shift 0.15) peaks
    at bin 14; scored only where the plane puts it (the default), it does not."""
    _, _, e = oblique
    rng = np.random.default_rng(4)
    obs = _moved(e.liquid[14], -3, -4) & e.interior
    obs ^= rng.random(obs.shape) < 0.1
    assert int(np.argmax(log_likelihood(e.liquid, e.interior, obs, shift=0.15))) == 14
    assert int(np.argmax(log_likelihood(e.liquid, e.interior, obs))) != 14


def test_session_mask_volumes_take_the_shift_and_refuse_a_bad_one(tapered):
    from liquidtwin.session._volumes import MaskVolumes
    args = (["cup"], [tapered], ["cup"], [], 50.0, 0.005, {})
    assert MaskVolumes(*args)._shift == 0.0                       # the default: SPEC's flat surface
    assert MaskVolumes(*args, shift=0.15)._shift == 0.15
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="shift"):
            MaskVolumes(*args, shift=bad)
