"""Measurement realism (liquidtwin.sensors): mask/pose noise, dropped frames, synthetic RGB.

References are independent of the implementation: morphological bands (cv2.erode/dilate),
connected components, rotation matrices and their log map written out here, Farnebäck optical
flow for the refraction displacement, closed-form Beer–Lambert transmission.
"""

import dataclasses
import math

import cv2
import numpy as np
import pytest

from liquidtwin.sensors import (
    TEXTURE_KINDS, MaskNoise, PoseNoise, RGBParams, SensorInputError, TextureParams, corrupt_mask,
    dropped_frames, noisy_poses, render_texture, synth_rgb,
)
from liquidtwin.recordings._interp import pose_noise_level, smooth_poses

# --------------------------------------------------------------------------- helpers


def _disc_mask(h=400, w=400):
    yy, xx = np.mgrid[0:h, 0:w]
    m = (xx - w / 2) ** 2 + (yy - h / 2) ** 2 < (0.35 * min(h, w)) ** 2
    m[20:40, 10:w - 10] = True           # a thin stream as well
    return m


def _band(mask, r):
    """Pixels within ~r px of the boundary (dilation minus erosion with a disc)."""
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    m8 = mask.astype(np.uint8)
    return (cv2.dilate(m8, k) > 0) & ~(cv2.erode(m8, k, borderType=cv2.BORDER_REPLICATE) > 0)


def _rotmat(q):
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                     2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                     2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
                    -1).reshape(q.shape[:-1] + (3, 3))


def _rotvec(r):
    """Log map of rotation matrices (..., 3, 3) → (..., 3), small and moderate angles."""
    cos = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1) / 2, -1, 1)
    ang = np.arccos(cos)
    v = np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                  r[..., 1, 0] - r[..., 0, 1]], -1)
    k = np.where(ang > 1e-9, ang / (2 * np.sin(np.maximum(ang, 1e-9))), 0.5)
    return v * k[..., None]


def _random_quats(rng, shape):
    q = rng.standard_normal(shape + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _scene(h=160, w=200):
    """A cup (label 1, red) and a bowl (label 2, blue); liquid: a bumpy pool in the middle."""
    yy, xx = np.mgrid[0:h, 0:w]
    labels = np.zeros((h, w), np.int32)
    labels[20:140, 10:50] = 1
    labels[110:155, 120:195] = 2
    mask = np.zeros((h, w), bool)
    mask[40:100, 70:150] = True
    thick = (mask * (1.0 + 0.5 * np.sin(xx / 4.0) * np.sin(yy / 5.0))).astype(np.float32)
    return thick, mask, labels, [(0.8, 0.1, 0.1), (0.1, 0.2, 0.85)]


_QUIET = dict(jpeg_quality=0, blur_px=0.0, motion_px=0.0)


def _params(**kw):
    tex = TextureParams(kind="noise", scale_px=4.0, colors=((0.15, 0.15, 0.15), (0.85, 0.8, 0.75)),
                        grain=0.0, seed=7)
    base = dict(texture=tex,
                vignette=0.0, light_gradient=(0.0, 0.0), exposure=1.0, **_QUIET)
    base.update(kw)
    return RGBParams(**base)


def _render(seed, thick, mask, labels, colors, **kw):
    return synth_rgb(np.random.default_rng(seed), liquid_thickness=thick, liquid_mask=mask,
                     labels=labels, object_colors=colors, **kw)


# --------------------------------------------------------------------------- determinism


def test_same_seed_same_output_different_seed_different():
    mask = _disc_mask(120, 140)
    a, b, c = (corrupt_mask(mask, np.random.default_rng(s)) for s in (1, 1, 2))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    poses = np.zeros((50, 2, 7))
    poses[..., 6] = 1
    a, b, c = (noisy_poses(poses, np.random.default_rng(s)) for s in (1, 1, 2))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    a, b, c = (dropped_frames(2000, np.random.default_rng(s)) for s in (1, 1, 2))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    for cls in (MaskNoise, PoseNoise, RGBParams, TextureParams):
        a, b, c = (cls.sample(np.random.default_rng(s)) for s in (1, 1, 2))
        assert a == b and a != c, cls
    thick, mask, labels, colors = _scene()
    a, b, c = (_render(s, thick, mask, labels, colors) for s in (3, 3, 4))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


# --------------------------------------------------------------------------- masks


def test_corrupt_mask_rates_match_parameters_exactly_without_ragged_edges():
    mask = _disc_mask()
    out = corrupt_mask(mask, np.random.default_rng(0), miss=0.1, false=0.02, ragged_px=0.0)
    miss_rate = (mask & ~out).sum() / mask.sum()
    false_rate = (~mask & out).sum() / (~mask).sum()
    assert abs(miss_rate - 0.1) < 2e-3 and abs(false_rate - 0.02) < 2e-3


def test_corrupt_mask_default_rates_are_parameters_plus_the_boundary_jitter():
    mask = _disc_mask()
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    perimeter = sum(cv2.arcLength(c, True) for c in contours)
    # a boundary offset ~ N(0, ragged²) moves E[max(offset, 0)] = 0.4·ragged px out (and as
    # much in) per px of boundary
    jitter = 0.4 * 1.5 * perimeter
    rates = []
    for s in range(3):
        out = corrupt_mask(mask, np.random.default_rng(s))   # miss 0.05, false 0.005, ragged 1.5
        rates.append(((mask & ~out).sum() / mask.sum(), (~mask & out).sum() / (~mask).sum()))
    miss, false = np.mean(rates, axis=0)
    assert abs(miss - (0.05 + jitter / mask.sum())) < 0.25 * jitter / mask.sum(), miss
    assert abs(false - (0.005 + jitter / (~mask).sum())) < 0.25 * jitter / (~mask).sum(), false


def test_misses_are_blobs_not_salt_and_specks_are_single_pixels():
    mask = _disc_mask()
    sizes = {}
    for share in (0.0, 1.0):
        out = corrupt_mask(mask, np.random.default_rng(5), miss=0.08, false=0.0, ragged_px=0.0,
                           blob_px=6.0, speck_share=share)
        missed = (mask & ~out).astype(np.uint8)
        n, _, stats, _ = cv2.connectedComponentsWithStats(missed, connectivity=4)
        sizes[share] = stats[1:, cv2.CC_STAT_AREA]
    # blobs: few large components; specks: nearly all isolated pixels (some touch by chance)
    assert sizes[0.0].mean() > 15 and len(sizes[0.0]) < 0.1 * sizes[0.0].sum()
    assert sizes[1.0].mean() < 1.3


def test_false_liquid_comes_as_small_blobs():
    mask = _disc_mask()
    out = corrupt_mask(mask, np.random.default_rng(2), miss=0.0, false=0.01, ragged_px=0.0,
                       speck_share=0.0, blob_px=4.0)
    wrong = (out & ~mask).astype(np.uint8)
    n, _, stats, _ = cv2.connectedComponentsWithStats(wrong, connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA]
    assert n > 10 and areas.max() < 150 and areas.mean() > 3


def test_ragged_edges_only_touch_the_boundary_band_and_move_both_ways():
    mask = _disc_mask()
    r = 2.0
    out = corrupt_mask(mask, np.random.default_rng(3), miss=0.0, false=0.0, ragged_px=r)
    changed = out != mask
    band = _band(mask, int(3 * r + 2))
    assert not (changed & ~band).any()                      # interior and far background intact
    added, removed = (out & ~mask).sum(), (mask & ~out).sum()
    perimeter = _band(mask, 1).sum() / 2
    assert added + removed > 0.5 * perimeter
    assert 0.4 < added / removed < 2.5


def test_mask_noise_none_is_identity_also_for_stacks():
    stack = np.stack([_disc_mask(64, 80), np.zeros((64, 80), bool), np.ones((64, 80), bool)])
    out = corrupt_mask(stack, np.random.default_rng(0), MaskNoise.NONE)
    assert out.dtype == np.bool_ and np.array_equal(out, stack)
    noisy = corrupt_mask(stack, np.random.default_rng(0))
    assert noisy.shape == stack.shape and not np.array_equal(noisy[0], stack[0])


# --------------------------------------------------------------------------- poses


def _true_poses(rng, t=4000, n=2):
    p = np.empty((t, n, 7))
    p[..., :3] = rng.uniform(-1, 1, (t, n, 3))
    p[..., 3:] = _random_quats(rng, (t, n))
    return p


def test_noisy_poses_unit_quaternions_and_white_noise_std():
    rng = np.random.default_rng(0)
    true = _true_poses(rng)
    sig_p, sig_r = 1e-3, 0.01
    out = noisy_poses(true, np.random.default_rng(1), pos_sigma_m=sig_p, rot_sigma_rad=sig_r,
                      drift_m=0.0, drift_rad=0.0)
    assert out.shape == true.shape and out.dtype == np.float64
    assert np.allclose(np.linalg.norm(out[..., 3:], axis=-1), 1.0, atol=1e-12)
    dp = (out[..., :3] - true[..., :3]).reshape(-1, 3)
    assert np.allclose(dp.std(0), sig_p, rtol=0.05) and np.allclose(dp.mean(0), 0, atol=0.1 * sig_p)
    r_err = _rotmat(out[..., 3:]) @ np.swapaxes(_rotmat(true[..., 3:]), -1, -2)  # world frame
    w = _rotvec(r_err).reshape(-1, 3)
    assert np.allclose(w.std(0), sig_r, rtol=0.05) and np.allclose(w.mean(0), 0, atol=0.1 * sig_r)


def test_noisy_poses_quaternion_signs_follow_the_input():
    t = np.linspace(0, 6 * math.pi, 600)
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    q = np.concatenate([np.sin(t / 2)[:, None] * axis, np.cos(t / 2)[:, None]], 1)  # continuous
    poses = np.concatenate([np.zeros((600, 3)), q], 1)                               # (T, 7) form
    out = noisy_poses(poses, np.random.default_rng(0))
    assert out.shape == (600, 7)
    assert (np.sum(out[1:, 3:] * out[:-1, 3:], -1) > 0).all()
    assert np.abs(out[:, 3:] - q).max() < 0.05              # same hemisphere as the input
    flipped = poses.copy()
    flipped[::2, 3:] *= -1                                   # same rotations, alternating signs
    out2 = noisy_poses(flipped, np.random.default_rng(0))
    signs = np.where(np.arange(600)[:, None] % 2 == 0, -1, 1)
    assert np.array_equal(out2[:, 3:], signs * out[:, 3:])


def test_zero_noise_is_identity_and_bias_shifts():
    rng = np.random.default_rng(4)
    true = _true_poses(rng, 30, 3)
    assert np.allclose(noisy_poses(true, rng, PoseNoise.NONE), true, atol=1e-12)
    f32 = noisy_poses(true.astype(np.float32), rng, PoseNoise.NONE)
    assert f32.dtype == np.float32
    out = noisy_poses(true, rng, PoseNoise.NONE, pos_bias_m=(0.01, 0.0, -0.02))
    assert np.allclose(out[..., :3] - true[..., :3], [0.01, 0.0, -0.02], atol=1e-12)
    rb = np.array([0.0, 0.1, 0.0])
    out = noisy_poses(true, rng, PoseNoise.NONE, rot_bias_rad=rb)
    w = _rotvec(_rotmat(out[..., 3:]) @ np.swapaxes(_rotmat(true[..., 3:]), -1, -2))
    assert np.allclose(w, rb, atol=1e-9)


def _tilt_series(t, rate=0.8):
    """A cup sliding at constant velocity while tilting at a constant rate about y: (T, 7)."""
    pos = np.stack([0.1 + 0.2 * t, -0.05 * t, np.full(len(t), 0.3)], 1)
    q = np.stack([np.zeros(len(t)), np.sin(rate * t / 2), np.zeros(len(t)), np.cos(rate * t / 2)], 1)
    return np.concatenate([pos, q], 1)


def _angle_deg(qa, qb):
    return np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(qa * qb, -1)), -1, 1)))


def test_smoothing_keeps_motion_linear_in_time():
    t = np.arange(0, 3, 1 / 60)
    p = _tilt_series(t)
    s = smooth_poses(t, p, 0.05, clip=None)                    # the local line alone, unclipped
    assert np.abs(s[:, :3] - p[:, :3]).max() < 1e-12          # linear translation, edges included
    assert _angle_deg(s[:, 3:], p[:, 3:]).max() < 0.01        # a constant-rate tilt (quaternions curve)
    assert np.array_equal(smooth_poses(t, p, 0.0), p)


def test_smoothing_changes_a_sharp_corner_no_more_than_the_noise():
    t = np.arange(0, 2, 1 / 60)
    x = np.where(t < 1.0, 0.0, 0.8 * (t - 1.0))                # at rest, then 0.8 m/s at once
    p = np.zeros((len(t), 7))
    p[:, 0], p[:, 6] = x, 1.0
    assert np.abs(smooth_poses(t, p, 0.05, clip=None)[:, 0] - x).max() > 3e-3   # the line cuts the corner
    assert np.abs(smooth_poses(t, p, 0.05)[:, 0] - x).max() < 1e-9              # noise-free: kept
    noisy = noisy_poses(p, np.random.default_rng(2), drift_m=0.0, drift_rad=0.0)
    s = smooth_poses(t, noisy, 0.05)
    assert np.abs(s[:, 0] - noisy[:, 0]).max() <= 3.0 * 1.3 * PoseNoise().pos_sigma_m   # clip at 3 noise levels
    away = np.abs(t - 1.0) > 0.25                                # beyond the corner's 4 σ reach
    rms = lambda e: np.sqrt(np.mean(e[away] ** 2))                              # noqa: E731
    assert rms(s[:, 0] - x) < 0.5 * rms(noisy[:, 0] - x)


def test_smoothing_takes_the_tracker_jitter_out_of_velocities():
    t = np.arange(0, 3, 1 / 60)
    true = np.stack([_tilt_series(t), _tilt_series(t, -0.5)], 1)              # (T, 2, 7)
    noisy = noisy_poses(true, np.random.default_rng(3), drift_m=0.0, drift_rad=0.0)
    s = smooth_poses(t, noisy, 0.05)
    assert s.shape == true.shape
    v = lambda x: np.diff(x[..., :3], axis=0) * 60                           # noqa: E731
    assert (v(s) - v(true)).std() < 0.1 * (v(noisy) - v(true)).std()         # 18x measured
    assert (s[..., :3] - true[..., :3]).std() < 0.4 * (noisy[..., :3] - true[..., :3]).std()
    w = lambda q: _rotvec(_rotmat(q[1:]) @ np.swapaxes(_rotmat(q[:-1]), -1, -2)) * 60  # noqa: E731
    assert (w(s[..., 3:]) - w(true[..., 3:])).std() < 0.1 * (w(noisy[..., 3:]) - w(true[..., 3:])).std()


def test_smoothing_handles_quaternion_signs_and_gaps():
    t = np.concatenate([np.arange(0, 1, 1 / 60), [2.0], np.arange(3, 4, 1 / 60)])   # a lone sample
    p = _tilt_series(t)
    noisy = noisy_poses(p, np.random.default_rng(5))
    flipped = noisy.copy()
    flipped[::3, 3:] *= -1                           # the same rotations, some signs flipped
    a, b = smooth_poses(t, noisy, 0.05), smooth_poses(t, flipped, 0.05)
    signs = np.where(np.arange(len(t))[:, None] % 3 == 0, -1, 1)
    assert np.allclose(b[:, 3:], signs * a[:, 3:], atol=1e-12)            # in the input's hemisphere
    assert np.allclose(a[:, :3], b[:, :3]) and np.allclose(np.linalg.norm(a[:, 3:], axis=1), 1)
    lone = len(np.arange(0, 1, 1 / 60))
    assert np.array_equal(a[lone], noisy[lone])        # nothing within 4 σ: kept as it is


def test_pose_drift_is_slow_with_the_stated_std():
    true = np.zeros((5000, 20, 7))
    true[..., 6] = 1.0
    tau, sd = 50.0, 1e-3
    out = noisy_poses(true, np.random.default_rng(8), pos_sigma_m=0.0, rot_sigma_rad=0.0,
                      drift_m=sd, drift_rad=0.0, drift_frames=tau)
    e = out[..., 0]
    assert abs(e.std() / sd - 1) < 0.1
    lag1 = (e[1:] * e[:-1]).mean() / (e * e).mean()
    assert abs(lag1 - math.exp(-1 / tau)) < 0.01
    white = noisy_poses(true, np.random.default_rng(8), drift_m=0.0, drift_rad=0.0)[..., 0]
    assert abs((white[1:] * white[:-1]).mean() / (white * white).mean()) < 0.02


# --------------------------------------------------------------------------- dropped frames


def test_dropped_frames_rate_bursts_and_first_frame():
    keep = dropped_frames(200_000, np.random.default_rng(0), rate=0.03, burst=2.5)
    assert keep.shape == (200_000,) and keep.dtype == np.bool_ and keep[0]
    assert abs((~keep).mean() - 0.03) < 0.003
    d = np.diff(np.concatenate([[0], (~keep).astype(np.int8), [0]]))
    runs = np.flatnonzero(d == -1) - np.flatnonzero(d == 1)
    assert abs(runs.mean() - 2.5) < 0.15 and runs.max() >= 8           # occasional long bursts
    bern = dropped_frames(200_000, np.random.default_rng(1), rate=0.1, burst=1 / 0.9)
    x = (~bern).astype(float) - 0.1
    assert abs((x[1:] * x[:-1]).mean() / (x * x).mean()) < 0.02          # independent drops
    apart = ~dropped_frames(50_000, np.random.default_rng(1), rate=0.2, burst=1.0)
    assert not (apart[1:] & apart[:-1]).any() and abs(apart.mean() - 0.2) < 0.01
    firsts = [dropped_frames(5, np.random.default_rng(s), rate=0.5, burst=1.0)[0]
              for s in range(200)]
    assert all(firsts)
    assert dropped_frames(100, np.random.default_rng(0), rate=0.0).all()
    assert dropped_frames(0, np.random.default_rng(0)).shape == (0,)


# --------------------------------------------------------------------------- textures and RGB


def test_textures_all_kinds_deterministic_and_not_flat():
    for kind in TEXTURE_KINDS:
        tp = TextureParams(kind=kind, scale_px=10.0, colors=((0.1, 0.2, 0.3), (0.9, 0.8, 0.6)),
                           seed=3)
        img = render_texture(tp, 60, 90)
        assert img.shape == (60, 90, 3) and img.dtype == np.float32
        assert img.min() >= 0 and img.max() <= 1 and img.std() > 0.05, kind
        assert np.array_equal(img, render_texture(tp, 60, 90))
    kinds = {TextureParams.sample(np.random.default_rng(s)).kind for s in range(60)}
    assert kinds == set(TEXTURE_KINDS)


def test_synth_rgb_shape_dtype_for_random_params():
    thick, mask, labels, colors = _scene(120, 170)
    for s in range(4):
        img = _render(s, thick, mask, labels, colors)
        assert img.shape == (120, 170, 3) and img.dtype == np.uint8 and img.std() > 5
    thick, mask, labels, colors = _scene(480, 640)
    assert _render(9, thick, mask, labels, colors).shape == (480, 640, 3)


def test_liquid_changes_pixels_only_in_and_around_the_mask():
    thick, mask, labels, colors = _scene()
    p = _params()
    zt, zm = np.zeros_like(thick), np.zeros_like(mask)
    wet = _render(1, thick, mask, labels, colors, params=p).astype(int)
    dry = _render(1, zt, zm, labels, colors, params=p).astype(int)
    changed = np.abs(wet - dry).sum(-1) > 6
    near = cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0     # mask + 4 px
    assert not (changed & ~near).any()
    assert changed[mask].mean() > 0.7
    pj = dataclasses.replace(p, jpeg_quality=70)              # JPEG blocks spread the change
    wet = _render(1, thick, mask, labels, colors, params=pj).astype(int)
    dry = _render(1, zt, zm, labels, colors, params=pj).astype(int)
    changed = np.abs(wet - dry).sum(-1) > 6
    near16 = cv2.dilate(mask.astype(np.uint8), np.ones((41, 41), np.uint8)) > 0  # 16 + 4 px
    assert not (changed & ~near16).any() and changed[mask].mean() > 0.7


def test_liquid_refracts_the_background_instead_of_painting_a_flat_colour():
    thick, mask, labels, colors = _scene()
    p = _params(refraction_px=6.0, absorption=(0.02, 0.02, 0.02), specular=0.0, fresnel=0.0,
                rim=0.0, liquid_blur_px=0.0, noise_read=0.0, noise_shot=0.0)
    wet = _render(0, thick, mask, labels, colors, params=p)
    dry = _render(0, np.zeros_like(thick), np.zeros_like(mask), labels, colors, params=p)
    gw, gd = (cv2.cvtColor(x, cv2.COLOR_RGB2GRAY) for x in (wet, dry))
    # Farnebäck flow: wet(x) ≈ dry(x + flow(x))
    flow = cv2.calcOpticalFlowFarneback(gw, gd, None, 0.5, 3, 9, 5, 5, 1.1, 0)
    mag = np.linalg.norm(flow, axis=-1)
    inner = cv2.erode(mask.astype(np.uint8), np.ones((13, 13), np.uint8)) > 0
    far = cv2.dilate(mask.astype(np.uint8), np.ones((31, 31), np.uint8)) == 0
    assert np.median(mag[inner]) > 1.0 and np.median(mag[far]) < 0.2
    h, w = gw.shape
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    back = cv2.remap(gd, xs + flow[..., 0], ys + flow[..., 1], cv2.INTER_LINEAR)
    err_shifted = np.abs(gw.astype(float) - back)[inner].mean()
    err_plain = np.abs(gw.astype(float) - gd)[inner].mean()
    assert err_shifted < 0.6 * err_plain                       # it is the background, displaced
    assert gw[inner].std() > 0.6 * gd[inner].std()      # texture survives: not a flat colour


def test_transmission_follows_beer_lambert_with_thickness():
    _, mask, labels, colors = _scene()
    a = np.array([0.3, 0.5, 0.8])
    tex = TextureParams(kind="noise", colors=((0.7, 0.7, 0.7), (0.8, 0.8, 0.8)), grain=0.0, seed=1)
    p = _params(absorption=tuple(a), specular=0.0, fresnel=0.0, rim=0.0, noise_read=0.0,
                noise_shot=0.0, thickness_ref=1.0, texture=tex)
    inner = cv2.erode(mask.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    means = [_render(0, mask * t, mask, labels, colors, params=p)[inner].astype(float).mean(0)
             for t in (1.0, 2.0)]
    assert np.allclose(means[1] / means[0], np.exp(-a), rtol=0.03)


def test_specular_highlight_sits_on_the_side_facing_the_light():
    h, w = 120, 120
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((xx - 60) ** 2 + (yy - 60) ** 2) / 40.0 ** 2
    mask = r2 < 1
    thick = (np.clip(1 - r2, 0, None) * 3).astype(np.float32)                    # a dome of liquid
    labels = np.zeros((h, w), np.int32)
    base = dict(light_dir=(0.6, 0.0, 0.8), fresnel=0.0, rim=0.0, noise_read=0.0, noise_shot=0.0,
                thickness_ref=1.0,
                texture=TextureParams(kind="noise", colors=((0.3,) * 3, (0.35,) * 3), seed=2))
    lit = _render(0, thick, mask, labels, [], params=_params(specular=1.0, shininess=40.0, **base))
    unlit = _render(0, thick, mask, labels, [], params=_params(specular=0.0, **base))
    glow = (lit.astype(int) - unlit).sum(-1)
    ys, xs = np.nonzero(glow > 0.5 * glow.max())
    assert glow.max() > 100 and xs.mean() > 65 and abs(ys.mean() - 60) < 6


def test_objects_take_their_colours_and_are_shaded():
    thick, mask, labels, colors = _scene()
    p = _params(object_texture=0.0, noise_read=0.0, noise_shot=0.0)
    img = _render(0, thick, mask, labels, colors, params=p).astype(float)
    red, blue = img[labels == 1].mean(0), img[labels == 2].mean(0)
    assert red[0] > 2 * red[1] and red[0] > 2 * red[2]
    assert blue[2] > 2 * blue[0] and blue[2] > 2 * blue[1]
    assert img[labels == 1][:, 0].std() > 3                      # shading, not a flat fill
    as_dict = _render(0, thick, mask, labels, {1: (204, 25, 25), 2: (25, 51, 217)}, params=p)
    assert np.abs(as_dict.astype(float) - img).max() <= 2


def test_without_liquid_frames_differ_only_by_sensor_noise():
    thick, mask, labels, colors = _scene()
    zt, zm = np.zeros_like(thick), np.zeros_like(mask)
    clean = _params(noise_read=0.0, noise_shot=0.0)
    a, b = (_render(s, zt, zm, labels, colors, params=clean) for s in (1, 2))
    assert np.array_equal(a, b)              # with fixed params the seed only drives the noise
    noisy = _params(noise_read=0.02, noise_shot=0.0, texture=TextureParams(
        kind="noise", colors=((0.4,) * 3, (0.6,) * 3), seed=1))
    a, b = (_render(s, zt, zm, labels, colors, params=noisy).astype(float) for s in (1, 2))
    d = (a - b)[..., 1]
    assert abs(d.mean()) < 0.2 and abs(d.std() / (0.02 * 255 * math.sqrt(2)) - 1) < 0.1
    d0 = d - d.mean()
    assert abs((d0[:, 1:] * d0[:, :-1]).mean() / (d0 * d0).mean()) < 0.05   # spatially white
    bg = (np.random.default_rng(0).random((160, 200, 3)) * 255).astype(np.uint8)
    c = _render(1, zt, zm, np.zeros_like(labels), [], params=_params(
        noise_read=0.0, noise_shot=0.0, vignette=0.0), background=bg)
    assert np.abs(c.astype(int) - bg).max() <= 1                # a given background passes through


# --------------------------------------------------------------------------- bad input


def test_bad_input_raises_clear_value_errors():
    thick, mask, labels, colors = _scene()
    rng = np.random.default_rng(0)
    kw = dict(liquid_thickness=thick, liquid_mask=mask, labels=labels, object_colors=colors)
    bad = [
        dict(liquid_thickness=thick[:-1]),
        dict(liquid_mask=mask.astype(np.uint8)),
        dict(labels=labels.astype(np.float32)),
        dict(labels=labels - 1),
        dict(liquid_thickness=-thick),
        dict(liquid_thickness=np.where(mask, np.nan, 0.0)),
        dict(object_colors=colors[:1]),
        dict(object_colors=[(1.5, 0, 0), (0, 0, 1)]),
        dict(object_colors={1: (1, 0, 0)}),
        dict(background=np.zeros((40, 50), np.uint8)),
        dict(params="bright"),
    ]
    for b in bad:
        with pytest.raises(ValueError):
            synth_rgb(rng, **{**kw, **b})
    with pytest.raises(SensorInputError, match="numpy.random.Generator"):
        synth_rgb(np.random.RandomState(0), **kw)
    with pytest.raises(SensorInputError, match="bool"):
        corrupt_mask(mask.astype(np.uint8), rng)
    with pytest.raises(ValueError):
        corrupt_mask(mask[0], rng)
    with pytest.raises(ValueError, match="miss"):
        MaskNoise(miss=2.0)
    with pytest.raises(ValueError):
        corrupt_mask(mask, rng, false=float("nan"))
    poses = np.zeros((5, 2, 7))
    poses[..., 6] = 1
    for p in (poses[..., :6], np.where(poses == 0, np.nan, poses), np.zeros((5, 2, 7)),
              poses.astype(bool)):
        with pytest.raises(ValueError):
            noisy_poses(p, rng)
    with pytest.raises(ValueError):
        noisy_poses(poses, rng, pos_bias_m=(1.0, 2.0))
    with pytest.raises(ValueError):
        dropped_frames(-1, rng)
    with pytest.raises(ValueError, match="rate"):
        dropped_frames(10, rng, rate=0.6, burst=1.0)
    with pytest.raises(ValueError):
        TextureParams(kind="marble")
    with pytest.raises(ValueError):
        RGBParams(light_dir=(0.0, 0.0))


def test_pose_noise_level_reads_the_white_noise_off_a_moving_series():
    """The tracker's white level per object, from the poses alone: the motion (a slide and a
    tilt) does not count; a drift barely does (its second differences are tiny)."""
    t = np.arange(0, 3, 1 / 60)
    true = np.stack([_tilt_series(t), _tilt_series(t, -0.5)], 1)
    for pos, rot in ((0.5e-3, np.radians(0.3)), (2e-3, np.radians(1.0))):
        noisy = noisy_poses(true, np.random.default_rng(7), pos_sigma_m=pos, rot_sigma_rad=rot)
        level = pose_noise_level(noisy)
        assert level.shape == (2, 2)
        assert np.allclose(level[:, 0], pos, rtol=0.15) and np.allclose(level[:, 1], rot, rtol=0.15)
    clean = pose_noise_level(true)                            # noise-free motion: ~no noise
    assert clean[:, 0].max() < 1e-12 and clean[:, 1].max() < 0.02 * np.radians(0.3)   # the tilt's curvature
    assert np.array_equal(pose_noise_level(true[:2]), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="K, n, 7"):
        pose_noise_level(true[:, 0])
