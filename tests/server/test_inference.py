"""Hidden-state inference (issue 5): δ-likelihood, the batched hypothesis bank, fill and
blockage banks on small generated scenes, and the generator's empty fill / planted blockage."""

import json
import math

import numpy as np
import pytest
import torch

from liquidtwin.generate import generate, parse_effect_extra
from liquidtwin.evaluate.blockage import routing
from liquidtwin.generate.catalog import QUICK_FILL, build_setup
from liquidtwin.inference import (DELTA, Bank, Posterior, disagreement, fill_hypotheses, frame_log_likelihood,
                                  infer_blockage, infer_fill, mask_log_likelihood, normalise, slack_radius, score)
from liquidtwin.inference.likelihood import blur_sigma
from liquidtwin.recordings import read_recording


# ------------------------------------------------------------------ likelihood

def test_delta_likelihood_matches_a_direct_product():
    rng = np.random.default_rng(0)
    observed = rng.random((3, 4)) < 0.4
    predicted = [rng.random((3, 4)) < p for p in (0.2, 0.5, 0.8)] + [observed.copy()]
    delta = 0.6                                  # big enough for the product to differ visibly
    direct = []
    for p in predicted:
        prod = 1.0
        for a, b in zip(p.ravel().tolist(), observed.ravel().tolist()):
            prod *= delta if a == b else 1.0 - delta
        direct.append(prod)
    ll = [mask_log_likelihood(p, observed, delta) for p in predicted]
    assert np.allclose(ll, np.log(direct), rtol=0, atol=1e-12)
    assert np.allclose(normalise(ll), np.array(direct) / sum(direct), atol=1e-12)
    assert int(np.argmax(ll)) == 3                           # the exact prediction wins
    # SPEC δ over a whole frame: agree·log δ + disagree·log(1 − δ), in float64.
    big = np.zeros((240, 320), bool)
    pred = big.copy()
    pred[:10, :10] = True
    assert mask_log_likelihood(pred, big) == pytest.approx((240 * 320 - 100) * math.log(DELTA)
                                                           + 100 * math.log(1 - DELTA), rel=1e-14)
    # Probability over time is the softmax of the running sums.
    post = Posterior.from_series(["a", "b"], [[0.0, -1.0], [-3.0, 0.0]], [0.1, 0.2], 0.0)
    assert np.allclose(post.probability_over_time[0], [1 / (1 + math.e ** -1), 1 / (1 + math.e)])
    assert np.allclose(post.probability, normalise([-3.0, -1.0])) and post.best == "b"
    with pytest.raises(ValueError):
        mask_log_likelihood(pred, big, delta=0.5)


def _unmatched(a: np.ndarray, b: np.ndarray, r: float) -> int:
    """Brute force: pixels of mask a with no pixel of mask b within r (every pair measured)."""
    pa, pb = np.argwhere(a), np.argwhere(b)
    if len(pa) == 0 or len(pb) == 0:
        return len(pa)
    d = np.sqrt(((pa[:, None, :] - pb[None, :, :]) ** 2).sum(-1)).min(1)
    return int((d > r).sum())


def test_slack_disagreement_matches_brute_force_and_forgives_a_shifted_blob():
    rng = np.random.default_rng(3)
    for _ in range(4):
        obs, pred = rng.random((30, 40)) < 0.04, rng.random((30, 40)) < 0.06
        assert disagreement(pred, obs, 0) == int((pred != obs).sum())          # 0: SPEC's exact pixels
        for r in (1.0, 1.5, 2.3, 5.0):
            want = _unmatched(obs, pred, r) + _unmatched(pred, obs, r)
            assert disagreement(pred, obs, r) == want
            assert disagreement(torch.as_tensor(pred), torch.as_tensor(obs), r) == want
    # The same 10x10 blob 6 px to the right: exact agreement counts both copies' non-overlap
    # (twice 60 px), more than predicting nothing (100 px); a 6 px slack forgives the shift.
    obs = np.zeros((60, 80), bool)
    obs[20:30, 20:30] = True
    pred = np.roll(obs, 6, axis=1)
    empty = np.zeros_like(obs)
    assert disagreement(pred, obs, 0) == 120 > disagreement(empty, obs, 0) == 100
    assert disagreement(pred, obs, 6) == 0 < disagreement(empty, obs, 6) == 100
    assert disagreement(pred, obs, 5) == 20                   # one column of each copy is 6 px away
    # The slack is given at 640x480 and scales with sqrt(pixels); 60x80 is 1/8 of each side.
    assert slack_radius(480, 640, 16) == 16 and slack_radius(240, 320, 16) == 8
    assert mask_log_likelihood(pred, obs, slack_px=48) == pytest.approx(60 * 80 * math.log(DELTA))
    assert mask_log_likelihood(pred, obs) == mask_log_likelihood(pred, obs, slack_px=0)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="slack"):
            slack_radius(240, 320, bad)


def _gauss_blur_brute(mask: np.ndarray, sigma: float) -> np.ndarray:
    """Brute force: every pixel gets every mask pixel's weight g(dy)·g(dx), g the Gaussian of
    σ sampled at whole pixels, cut at ceil(4σ) and normalised to sum 1; zero outside."""
    r = int(math.ceil(4 * sigma))
    g = np.exp(-np.arange(-r, r + 1) ** 2 / (2 * sigma ** 2))
    g /= g.sum()
    out = np.zeros(mask.shape)
    for y, x in np.argwhere(mask):
        for i in range(-r, r + 1):
            for j in range(-r, r + 1):
                if 0 <= y + i < mask.shape[0] and 0 <= x + j < mask.shape[1]:
                    out[y + i, x + j] += g[i + r] * g[j + r]
    return out


def test_blurred_disagreement_matches_brute_force_and_keeps_amounts():
    rng = np.random.default_rng(5)
    for sigma in (0.7, 1.5, 3.0):
        obs, pred = rng.random((24, 30)) < 0.05, rng.random((24, 30)) < 0.08
        want = np.abs(_gauss_blur_brute(pred, sigma) - _gauss_blur_brute(obs, sigma)).sum()
        assert disagreement(pred, obs, sigma_px=sigma) == pytest.approx(want, rel=1e-4)
        assert disagreement(torch.as_tensor(pred), torch.as_tensor(obs), sigma_px=sigma) == pytest.approx(want, rel=1e-4)
    assert disagreement(pred, obs, sigma_px=0.0) == int((pred != obs).sum())     # no blur: SPEC's exact pixels
    # What the blur is for. (1) Amounts: a 12x12 blob observed, predicted a quarter of its
    # pixels (every 4th column) in place. A slack of 3 px forgives that entirely (every
    # observed pixel has predicted liquid within 3 px); a blur of 3 px does not: the thin
    # prediction lies inside the blob, so its blur is below the blob's everywhere and it
    # disagrees on exactly its 108 missing pixels.
    obs = np.zeros((40, 40), bool)
    obs[14:26, 14:26] = True
    thin = np.zeros_like(obs)
    thin[14:26, 14:26:4] = True
    assert disagreement(thin, obs, 3.0) == 0
    assert disagreement(thin, obs, sigma_px=3.0) == pytest.approx(144 - 36, rel=1e-6)
    # (2) Drops: six 2x2 drops, each predicted 3 px off. Exact pixels count every drop twice
    # (48), worse than predicting no liquid (24); blurred, the misplaced drops (15.6) beat none (23.9).
    drops = np.zeros((40, 40), bool)
    for y, x in ((8, 8), (8, 20), (20, 12), (30, 28), (16, 30), (28, 6)):
        drops[y:y + 2, x:x + 2] = True
    off, none = np.roll(drops, 3, axis=1), np.zeros_like(drops)
    assert disagreement(off, drops) == 48 > disagreement(none, drops) == 24
    assert disagreement(off, drops, sigma_px=3.0) < 0.7 * disagreement(none, drops, sigma_px=3.0)
    # A blob much wider than the blur is still charged for its shift (d px per edge and row).
    shifted = np.roll(obs, 2, axis=1)
    assert disagreement(shifted, obs, sigma_px=3.0) == pytest.approx(48, rel=0.1)
    assert disagreement(obs, obs, sigma_px=3.0) == 0.0
    # Nothing predicted: the blur moves no liquid out of the image here, so all 144 pixels.
    assert disagreement(np.zeros_like(obs), obs, sigma_px=3.0) == pytest.approx(144, rel=1e-5)
    # Scaled with the image as the slack; refused when negative, not finite, or with a slack.
    assert blur_sigma(480, 640, 16) == 16 and blur_sigma(240, 320, 16) == 8
    sigma = blur_sigma(40, 40, 40.0)
    assert mask_log_likelihood(thin, obs, blur_px=40.0) == pytest.approx(
        frame_log_likelihood(disagreement(thin, obs, sigma_px=sigma), 1600), rel=1e-12)
    assert mask_log_likelihood(thin, obs, blur_px=40.0) < mask_log_likelihood(obs, obs, blur_px=40.0)
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="blur"):
            mask_log_likelihood(thin, obs, blur_px=bad)
    with pytest.raises(ValueError, match="not both"):
        mask_log_likelihood(thin, obs, slack_px=4.0, blur_px=4.0)


# ------------------------------------------------------------------ generated scenes

@pytest.fixture(scope="module")
def pour(tmp_path_factory):
    """Two quick partial pours of the same seed, 30 % and 90 % full, perfect sensors (a partial
    pour tips out only what lies above its tilt, so the poured amount depends on the fill)."""
    d = tmp_path_factory.mktemp("pours")
    out = {}
    for f in (0.3, 0.9):
        generate("pour_partial", d / f"p{f}.mcap", seed=1, quick=True, noise=False,
                 choices={"source": "cup", "target": "bowl", "fraction": f})
        out[f] = read_recording(d / f"p{f}.mcap", images=False)
    return out


def test_bank_draws_particles_at_its_radius_scale():
    # One particle 0.5 m in front of a camera, nothing observed: the disagreement (exact pixels)
    # is the disc the bank draws, whose area is π (fx · s · r / depth)² for radius scale s.
    from liquidtwin.camera import Camera
    from liquidtwin.inference import Hypothesis
    from liquidtwin.sim import FluidModel, particle_radius
    model = FluidModel.create(0.02, objects=[])
    cam = Camera.look_at((0.0, 0.0, 0.5), (0.0, 0.0, 0.0), width=320, height=240, fx=400.0)
    hyp = Hypothesis("one", (), torch.zeros(1, 3), torch.zeros(1, 3))
    r_m = particle_radius(float(model.spacing))
    empty = torch.zeros(240, 320, dtype=torch.bool)
    for s in (1.0, 0.6):
        bank = Bank(model, [hyp], (), radius_scale=s)
        bank.start(torch.zeros(0, 7))
        drawn = float(bank.observe(cam, empty)[0])
        disc = math.pi * (400.0 * s * r_m / 0.5) ** 2
        assert abs(drawn - disc) < 0.1 * disc + 4, (s, drawn, disc)
    with pytest.raises(ValueError, match="radius scale"):
        Bank(model, [hyp], (), radius_scale=0.0)


def test_batched_bank_equals_sequential_runs(pour):
    # float64, so that the 2 m offset costs no precision: float32 rounds positions 2 m out to
    # 0.24 µm, and a pouring splash amplifies any rounding difference to mm within ~0.3 s.
    rec = pour[0.3]
    scene, hyps = fill_hypotheses(rec.spec, "source", (0.3, 0.9), scale=QUICK_FILL)
    assert hyps[0].x.shape[0] < hyps[1].x.shape[0]
    bank = Bank(scene.model, hyps, scene.occluders, tracking="warp_field", dtype=torch.float64)
    ll, t = score(bank, rec, scene.model.dt, camera="thermal", frames=45)
    assert len(t) > 10
    for k in range(2):
        alone = bank.single(k)                       # alone, at the origin
        ll1, t1 = score(alone, rec, scene.model.dt, camera="thermal", frames=45)
        a, b = bank.particles(k), alone.particles(0)
        assert a.shape == b.shape
        assert float((a - b).abs().max()) < 1e-6
        assert np.array_equal(ll[:, k], ll1[:, 0]) and np.array_equal(t, t1)
    # The hypotheses really are apart: hypothesis 1 sits one offset along +x in the bank.
    assert float(bank.state.x[:, 0].max()) > bank.offset_m - 0.5


def test_fill_bank_ranks_the_truth_first_on_two_fills(pour):
    # Each quick pour is told nothing about its fill; hypotheses empty / 30 / 90 % (× QUICK_FILL).
    for truth, rec in pour.items():
        post = infer_fill(rec, fractions=(0.0, 0.3, 0.9), scale=QUICK_FILL, tracking="open_loop")
        assert post.best == f"{round(truth * 100)} %", (truth, post.names, post.probability)
        assert post.probability_over_time.shape == (post.frames, 3)
        assert np.allclose(post.probability_over_time.sum(1), 1.0)


def test_blockage_bank_finds_a_full_leg(tmp_path):
    path = tmp_path / "pipe.mcap"
    g = generate("pipe", path, seed=3, quick=True, noise=False, effects=[("blockage", 1.0, {"leg": 0.0})])
    rec = read_recording(path, images=False)
    post = infer_blockage(rec, hypotheses=("none", "left_full"), tracking="open_loop")
    assert post.best == "left_full", post.probability
    # Run one after another (the default) the two are the same scene until liquid reaches the
    # plug, and score bit-identically: exactly even odds until 1.5 s. The cup's stream enters
    # the inlet at ~1.3 s and must still fall down the stem and run 6 cm to the plug; the two
    # first differ at 1.67 s. Batched 2 m apart they already differ at 1.37 s.
    early = post.times_s < 1.5
    assert early.sum() > 20 and np.all(post.probability_over_time[early] == 0.5)
    truth = json.loads(g.truth.read_text())["effect"]         # the truth, after the analysis
    assert truth["extra"]["leg"] == 0.0 and truth["value"] == 1.0
    # The scene routes the liquid as the thesis's rig does (read from the truth, after the
    # analysis): all of it into the inlet, none through the plugged left leg, the rest into
    # the right bowl (quick: some still in the pipe).
    setup = build_setup("pipe", np.random.default_rng(0), True)
    went = routing(setup, np.load(path.with_suffix(".truth.npz"))["particles"])
    assert went["entered_inlet"] >= 0.95 and went["left_bowl"] <= 0.02 and went["right_bowl"] >= 0.3, went


# ------------------------------------------------------------------ generator support

def test_empty_fill_generates_and_the_empty_hypothesis_wins(tmp_path):
    path = tmp_path / "empty.mcap"
    g = generate("pour_hold", path, seed=2, quick=True, noise=False, choices={"source": "cup", "fraction": 0.0})
    assert g.particles == 0 and g.masks > 10
    truth = json.loads(g.truth.read_text())
    assert truth["fill_ml"]["true"] == {"source": 0.0}
    rec = read_recording(path, images=False)
    assert not any(m[1].any() for m in rec.masks.values())
    assert len(rec.spec.fills) == 0                       # an empty source states no fill
    post = infer_fill(rec, container="source", fractions=(0.0, 0.6), scale=QUICK_FILL, tracking="open_loop",
                      frames=90)
    assert post.best == "empty" and post.info["particles"]["empty"] == 0


def test_effect_extras_parse_and_fail_clearly():
    assert parse_effect_extra("blockage=1.0:leg=right") == ("blockage", 1.0, {"leg": 1.0})
    assert parse_effect_extra("blockage:leg=left") == ("blockage", None, {"leg": 0.0})
    assert parse_effect_extra("drag=2") == ("drag", 2.0, {})
    with pytest.raises(ValueError, match="KEY=VALUE"):
        parse_effect_extra("blockage=1:leg")
    with pytest.raises(ValueError, match="not a number"):
        parse_effect_extra("blockage=1:leg=middle")
    from liquidtwin.generate import sample_effect
    with pytest.raises(ValueError, match="unknown extra"):
        sample_effect("drag", np.random.default_rng(0), 2.0, {"leg": 1.0})
    # Fixed extras leave the seed's other draws alone.
    a = sample_effect("blockage", np.random.default_rng(5), 1.0)
    b = sample_effect("blockage", np.random.default_rng(5), 1.0, {"leg": 1.0 - a.extra["leg"]})
    assert b.extra["leg"] == 1.0 - a.extra["leg"]


def test_bad_requests_fail_clearly(pour):
    rec = pour[0.3]
    with pytest.raises(ValueError, match="fill fractions"):
        infer_fill(rec, fractions=(0.3, 1.5))
    with pytest.raises(KeyError, match="no container"):
        infer_fill(rec, container="table")
    with pytest.raises(ValueError, match="pipe_junction"):
        infer_blockage(rec)
    with pytest.raises(ValueError, match="tracking mode"):
        infer_fill(rec, tracking="telepathy", fractions=(0.3,))
    with pytest.raises(ValueError, match="slack"):
        infer_fill(rec, slack_px=-2.0)
    with pytest.raises(ValueError, match="radius scale"):
        infer_fill(rec, radius_scale=float("nan"))
    torch.set_num_threads(1)


def test_evaluate_rejects_a_bad_likelihood_before_generating(tmp_path, capsys):
    from liquidtwin.cli import main
    for kind, opt, val, says in (("fill", "--slack", "-1", "--delta/--slack"), ("blockage", "--delta", "0.4", "--delta/--slack"),
                                 ("fill", "--slack", "nan", "--delta/--slack"), ("blockage", "--partial", "1", "--partial"),
                                 ("fill", "--radius-scale", "-0.5", "--radius-scale")):
        with pytest.raises(SystemExit, match=says):
            main(["evaluate", kind, "--quick", opt, val, "--data", str(tmp_path / "d"), "--out", str(tmp_path / "o")])
    with pytest.raises(SystemExit):                       # the model's cap is checked by the parser
        main(["evaluate", "fill", "--quick", "--max-correction", "0", "--data", str(tmp_path / "d"),
              "--out", str(tmp_path / "o")])
    assert "--max-correction: takes a number of rest spacings > 0" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()                  # nothing was generated


def test_pipe_cases_plant_the_partial_plug_they_name():
    from liquidtwin.evaluate.blockage import pipe_cases
    cases = {c.truth: c for c in pipe_cases(quick=True, base_seed=7, partial=0.25)}
    assert cases["left_partial"].effects() == [("blockage", 0.25, {"leg": 0.0})]
    assert cases["right_full"].effects() == [("blockage", 1.0, {"leg": 1.0})] and cases["none"].effects() == []
    # Recordings are cached by name: a partial plug of another height is another recording.
    assert cases["left_partial"].name == "pipe-left_partial0.25-s8-q" and cases["none"].name == "pipe-none-s7-q"
    assert pipe_cases(quick=True, base_seed=7, partial=0.5)[1].name != cases["left_partial"].name
