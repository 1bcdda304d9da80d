"""Precision–recall with slack against a brute-force reference, AUC sanity, the optical-flow
baseline and a short training run on a synthetic moving-liquid sequence (issue 8)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from liquidtwin.perception import auc, baseline_scores, pr_auc, pr_curve
from liquidtwin.perception.data import Clip
from liquidtwin.perception.train import TrainConfig, detect, encode_clips, train


def _brute(scores, truth, slack, tau):
    """Precision and recall at threshold tau by looping over pixels (Chebyshev distance)."""
    pred = scores >= tau
    t_n, h, w = truth.shape
    tp_pred = rec = 0
    for t in range(t_n):
        for i in range(h):
            for j in range(w):
                win = (t, slice(max(i - slack, 0), i + slack + 1), slice(max(j - slack, 0), j + slack + 1))
                if pred[t, i, j] and truth[win].any():
                    tp_pred += 1
                if truth[t, i, j] and pred[win].any():
                    rec += 1
    n_pred = int(pred.sum())
    return (tp_pred / n_pred if n_pred else 1.0), rec / int(truth.sum())


@pytest.mark.parametrize("slack", [0, 1, 2])
def test_pr_curve_matches_brute_force(slack):
    rng = np.random.default_rng(slack)
    truth = rng.random((2, 12, 15)) < 0.15
    scores = np.clip(0.5 * truth + 0.7 * rng.random(truth.shape), 0, 1).astype(np.float32)
    scores = np.round(scores, 2)                       # scores sit on bin edges: no binning ambiguity
    p, r, thr = pr_curve(scores, truth, slack, bins=100)
    for tau in (0.0, 0.2, 0.45, 0.7, 0.9):
        k = int(round(tau * 100))
        assert thr[k] == pytest.approx(tau)
        bp, br = _brute(scores, truth, slack, tau - 1e-9)
        assert p[k] == pytest.approx(bp) and r[k] == pytest.approx(br)


def test_auc_perfect_one_random_positive_rate_and_slack_helps():
    rng = np.random.default_rng(0)
    truth = np.zeros((4, 60, 80), bool)
    truth[:, 20:30, 30:40] = True
    assert auc(truth.astype(np.float32), truth) == pytest.approx(1.0, abs=1e-3)
    rate = truth.mean()
    assert auc(rng.random(truth.shape), truth) == pytest.approx(rate, abs=0.01)
    shifted = np.roll(truth, 2, axis=2).astype(np.float32)    # right place, 2 px off
    assert auc(shifted, truth, 0) < 0.9 < auc(shifted, truth, 2)


def test_pr_curve_rejects_bad_input():
    with pytest.raises(ValueError, match="differ in shape"):
        pr_curve(np.zeros((4, 5)), np.zeros((5, 4), bool))
    with pytest.raises(ValueError, match="NaN"):
        pr_curve(np.full((4, 5), np.nan), np.zeros((4, 5), bool))
    with pytest.raises(ValueError, match="slack"):
        pr_curve(np.zeros((4, 5)), np.zeros((4, 5), bool), -1)
    assert pr_auc([1.0, 1.0], [1.0, 0.0]) == pytest.approx(1.0)


def _moving_liquid(seed: int, t_n: int = 16, h: int = 48, w: int = 64) -> Clip:
    """A textured static background with a falling, faintly refracting 'stream' of blobs:
    the liquid is near-invisible in any single frame and shows up by moving."""
    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur((rng.random((h, w, 3)) * 255).astype(np.uint8), (0, 0), 1.5)
    x0 = int(rng.integers(16, w - 16))
    frames, masks = [], []
    for t in range(t_n):
        m = np.zeros((h, w), np.uint8)
        for k in range(4):
            y = (6 * t + 12 * k) % h
            cv2.circle(m, (x0 + int(2 * np.sin(t + k)), y), 3, 1, -1)
        shift = np.roll(bg, 2, axis=0)
        img = np.where(m[..., None] > 0, (0.85 * shift + 30).astype(np.uint8), bg)
        img = np.clip(img.astype(int) + rng.integers(-4, 5, img.shape), 0, 255).astype(np.uint8)
        frames.append(img)
        masks.append(m > 0)
    return Clip(f"synthetic{seed}", np.stack(frames), np.stack(masks))


def test_flow_baseline_finds_moving_liquid_better_than_chance():
    clip = _moving_liquid(0)
    s = baseline_scores(clip.frames)
    assert s.shape == clip.masks.shape and 0 <= s.min() and s.max() <= 1
    assert auc(s, clip.masks, 2) > 3 * clip.masks.mean()


def test_training_learns_to_detect_moving_liquid_on_unseen_sequences():
    train_clips = [_moving_liquid(s) for s in range(3)]
    test_clip = _moving_liquid(10)
    cfg = TrainConfig(kind="fcn", input_type="grey_flow", crop_iterations=80, full_iterations=20, crop_px=32,
                      window=2, batch=4, lr=5e-3)
    net, info = train(train_clips, cfg, progress=False)
    h = info["loss_history"]
    assert np.mean(h[-10:]) < 0.7 * np.mean(h[:10])
    probs = detect(net, encode_clips([test_clip], "grey_flow")[0])
    assert auc(probs, test_clip.masks) > 5 * test_clip.masks.mean()


def test_training_is_repeatable_bit_for_bit_with_augmentation():
    """The same clips, configuration and seed give the same weights, augmentation included: a
    changed AUC between two runs is a changed dataset or code, never training noise."""
    clips = [_moving_liquid(s) for s in range(2)]
    cfg = TrainConfig(kind="fcn", input_type="grey_flow", fusion="late", crop_iterations=12, full_iterations=6,
                      crop_px=32, window=2, batch=2, augment="flip,colour")
    a, b = (train(clips, cfg, progress=False)[0].state_dict() for _ in range(2))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    other = train(clips, TrainConfig(**{**cfg.__dict__, "seed": 1}), progress=False)[0].state_dict()
    assert not all(torch.equal(a[k], other[k]) for k in a)


def test_training_length_is_chosen_on_held_out_clips_and_the_watched_ones_never_choose():
    """``select_every``: checkpoints every N steps and at the last; the weights returned are
    the checkpoint with the best held-out AUC — re-scored independently here, they give
    exactly that AUC — and scoring extra clips for the record changes nothing."""
    train_clips = [_moving_liquid(s) for s in range(2)]
    held_out, watched = [_moving_liquid(20)], [_moving_liquid(30)]
    cfg = TrainConfig(kind="fcn", input_type="grey_flow", crop_iterations=30, full_iterations=15, crop_px=32,
                      window=2, batch=2, lr=5e-3, select_every=10)
    net, info = train(train_clips, cfg, progress=False, select_on=held_out, watch=watched)
    points = info["checkpoints"]
    assert [p["step"] for p in points] == [10, 20, 30, 40, 45]
    assert all(0 <= p["select_auc"] <= 1 and 0 <= p["watch_auc"] <= 1 for p in points)
    best = max(points, key=lambda p: p["select_auc"])
    assert info["selected_step"] == best["step"] and info["selected_on"] == ["synthetic20"]
    rescored = auc(detect(net, encode_clips(held_out, "grey_flow")[0]), held_out[0].masks, 0)
    assert rescored == pytest.approx(best["select_auc"], abs=1e-6)
    # the held-out AUCs differ along the way, so the choice is not trivially the last step
    assert len({round(p["select_auc"], 6) for p in points}) > 1

    unwatched, info2 = train(train_clips, cfg, progress=False, select_on=held_out)
    assert info2["selected_step"] == info["selected_step"] and "watch_auc" not in info2["checkpoints"][0]
    for (k, a), b in zip(net.state_dict().items(), unwatched.state_dict().values()):
        assert torch.equal(a, b), k

    _, info3 = train(train_clips, TrainConfig(**{**cfg.__dict__, "select_every": 0}), progress=False)
    assert "checkpoints" not in info3
    with pytest.raises(ValueError, match="held-out"):
        train(train_clips, cfg, progress=False)


class _Always:
    """A stand-in random stream whose coin always lands 'augment', with real draws otherwise."""

    def __init__(self, seed=0):
        self._rng = np.random.default_rng(seed)

    def random(self):
        return 0.0

    def __getattr__(self, name):
        return getattr(self._rng, name)


def test_flip_augmentation_mirrors_the_flow_as_farneback_sees_mirrored_frames():
    """The flipped window's flow planes are compared with Farnebäck run on the mirrored frames
    (an independent computation): they agree to < 0.02 where the texture moves, while the
    unmirrored angle would be off by ~2 in the cosine for horizontal motion."""
    from liquidtwin.perception.flow import flow_planes
    from liquidtwin.perception.train import augment_window
    rng = np.random.default_rng(3)
    bg = cv2.GaussianBlur((rng.random((60, 80)) * 255).astype(np.uint8), (0, 0), 2.0)
    a, b = bg, np.roll(np.roll(bg, 2, axis=1), 1, axis=0)          # moving right and down
    image = b[None].astype(np.float32) / 255.0
    x = np.concatenate([image, flow_planes(a, b)])[None]            # (T=1, grey + 3 flow, h, w)
    y = np.zeros((1, 60, 80), bool)
    y[0, 10:20, 5:15] = True
    xf, yf = augment_window(_Always(), x, y, "grey_flow", "flip")
    mirrored = flow_planes(np.ascontiguousarray(a[:, ::-1]), np.ascontiguousarray(b[:, ::-1]))
    inner = (slice(8, -8), slice(8, -8))
    moving = mirrored[2][inner] > 0.1
    assert moving.mean() > 0.9
    for plane in range(3):
        assert np.abs(xf[0, 1 + plane][inner][moving] - mirrored[plane][inner][moving]).mean() < 0.02
    assert np.abs(x[0, 2][inner][moving] - mirrored[1][inner][moving]).mean() > 1.5
    assert np.array_equal(xf[0, 0], image[0, :, ::-1]) and np.array_equal(yf[0], y[0, :, ::-1])
    zero = np.stack([np.zeros((60, 80)), np.ones((60, 80)), np.zeros((60, 80))]).astype(np.float32)
    still = np.concatenate([image, zero])[None]                     # zero flow stays sin 0, cos 1
    assert np.array_equal(augment_window(_Always(), still, y, "grey_flow", "flip")[0][0, 1:], zero)


def test_colour_augmentation_changes_only_the_image_planes():
    from liquidtwin.perception.train import augment_window
    rng = np.random.default_rng(0)
    x = rng.random((3, 6, 8, 8)).astype(np.float32)                 # rgb_flow: 3 image + 3 flow planes
    y = rng.random((3, 8, 8)) > 0.5
    xc, yc = augment_window(_Always(1), x, y, "rgb_flow", "colour")
    assert np.array_equal(xc[:, 3:], x[:, 3:]) and np.array_equal(yc, y)
    assert 0 <= xc[:, :3].min() and xc[:, :3].max() <= 1 and not np.allclose(xc[:, :3], x[:, :3])
    # each output channel is one input channel under one affine map, the same in every frame
    # of the window (checked where no clipping can occur: inputs in [0.2, 0.6])
    for c in range(3):
        residuals = []
        for src in range(3):
            keep = (x[:, src] > 0.2) & (x[:, src] < 0.6)
            f = np.polyfit(x[:, src][keep], xc[:, c][keep], 1)
            residuals.append(np.abs(np.polyval(f, x[:, src][keep]) - xc[:, c][keep]).max())
        assert min(residuals) < 1e-5 and sorted(residuals)[1] > 0.1
    flow = x[:, 3:]
    assert np.array_equal(augment_window(_Always(), flow, y, "flow", "colour")[0], flow)


def test_augmentation_draws_from_its_own_stream_and_bad_names_are_refused():
    """With colour augmentation (which leaves the masks alone) training sees the same windows
    and crops as without: the truth batches match exactly, so an A/B comparison isolates
    the augmentation."""
    from liquidtwin.perception.inputs import parse_augment
    from liquidtwin.perception.train import _sample
    clips = [_moving_liquid(s) for s in range(2)]
    inputs = encode_clips(clips, "rgb")
    base = TrainConfig(kind="fcn", input_type="rgb", crop_px=32, window=2, batch=3)
    plain_rng, aug_rng = np.random.default_rng(0), np.random.default_rng(0)
    colour = TrainConfig(**{**base.__dict__, "augment": "colour"})
    for crop in (True, True, False):
        x0, y0 = _sample(plain_rng, inputs, clips, base, crop)
        x1, y1 = _sample(aug_rng, inputs, clips, colour, crop, aug_rng=np.random.default_rng([0, 1]))
        assert torch.equal(y0, y1) and not torch.equal(x0, x1)
    assert parse_augment(" colour ,flip") == "flip,colour" and parse_augment("none") == ""
    with pytest.raises(ValueError, match="unknown augmentation blur"):
        parse_augment("flip,blur")
    with pytest.raises(ValueError, match="augment must be"):
        train(clips, TrainConfig(**{**base.__dict__, "augment": "colour,flip"}), progress=False)
