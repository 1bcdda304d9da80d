"""SPNets + perception (SOLVEPERCEPTION in the PBF inner loop): distance fields against brute
force, the image window against the full image, float64 gradcheck through the layer (particle
positions and the blending net's weights), occluded particles untouched, a displaced blob pulled
onto the observation by the solver term, the shipped weights, and sessions on generated pours."""

import dataclasses
import io

import numpy as np
import pytest
import torch
from liquidtwin.camera import Camera, iou, sphere_coverage, sphere_radius_px, visible
from liquidtwin.scenes.shapes import sample_grid, box
from liquidtwin.sim import FluidModel, fused, lattice, make_state, particle_radius, step
from liquidtwin.tracking import (BlendNet, Observation, PerceptionWeightsError, SPNetsPerception, distance_field,
                                 load_blend_net, nearest_vectors, solve_perception)
from liquidtwin.tracking import perception as P
from liquidtwin.tracking.perception import WEIGHTS
from realisations import SKINS, realisation

H_K, SPACING = 0.011, 0.00605
R_M = particle_radius(SPACING)
#: The generated pours of the session test (quick partial pours of a 30 % cup into a bowl:
#: 320x240, ~320 particles; the liquid comes to rest in view, where a tracker can hold it).
POUR_SCENE, POUR_CHOICES = "pour_partial", {"source": "cup", "fraction": 0.3}
POUR_SEEDS = (1, 2, 3)
#: Mean IOU gain over the pours asserted per closed-loop tracker. One pour's gain is the
#: spread of a chaotic rollout: on quick hold pours seed 1 measured open loop 0.292,
#: spnets_perception 0.392 when the test was written (an AVX2 CPU) and 0.353 / 0.368 on an
#: AVX-512 one at stop 39,
#: and on quick dump pours (seeds 1–3, AVX-512) spnets_perception gained −0.004, +0.084,
#: +0.030. On these partial pours (AVX-512): spnets_perception +0.207, +0.125, +0.234;
#: warp field +0.199, −0.011, +0.159. Since stop 41's world (its cohesion no longer raised by
#: its extra solver iterations: generate/world.py): spnets_perception +0.201, +0.033, +0.262;
#: warp field +0.183, +0.054, +0.116; MAP filter +0.061, +0.012, +0.077.
#: Stop 47 replayed the same three pours in other float roundings of the model (neighbour
#: skins, ``realisations``; ``bench/perturbed.py S ... -k generated_pours``, which also
#: regenerates the pours in that rounding): skin 0 (the default since) spnets_perception
#: +0.243, +0.157, +0.254, warp field +0.077, +0.037, +0.108, MAP filter −0.023, −0.016,
#: +0.034; skin 0.1 h (the numerics of the run above) exactly its numbers; skin 0.3 h
#: spnets_perception +0.188, +0.201, +0.139, warp field +0.032, +0.153, +0.035, MAP filter
#: −0.017, −0.040, −0.100. The MAP filter's mean gain, +0.050 in one rounding, is −0.002 and
#: −0.052 in the others: no gain to assert, so it is not replayed here (README, issue 5:
#: the MAP column is below open loop on quick rows too). Its scores and choices are tested on
#: hand-made cases in test_tracking_map.py. The margins below are asserted on the mean over
#: two realisations (skins 0 and 0.1 h: 18 replays, the test's time budget), where the
#: smallest of the six warp-field gains was +0.037 and the mean +0.086.
#: Stop 48 (per-particle collision pieces: the same physics, so the pours and the replays are
#: other realisations): spnets_perception +0.067, +0.155, +0.080 (skin 0), +0.203, +0.001,
#: +0.167 (0.1 h): seed 2 gained 0.001 in one realisation, so the every-pour check is on
#: each pour's mean over the two (+0.078 for seed 2). Warp field −0.078, −0.028, +0.054 and +0.004, −0.043, +0.131, mean +0.007.
#: The warp field's gain on these quick pours is within the pour-to-pour spread, so only
#: SPNets+perception is asserted here; the warp field's pull is tested on hand-made cases
#: (test_tracking_warp.py) and its gain over open loop by the benchmark's 18 pours (README,
#: issue 5).
POUR_MARGIN = {"spnets_perception": 0.05}
CAMERA = "thermal"


def _camera(width=160, height=120):
    return Camera.look_at((0.0, 0.12, 0.45), (0.0, 0.05, 0.0), width=width, height=height, fov_y_deg=40.0)


def _blob(centre, half=0.02, spacing=SPACING):
    p = lattice(-np.full(3, half), np.full(3, half), spacing)
    p = p[(p**2).sum(1) <= half * half]
    return torch.as_tensor(p + np.asarray(centre), dtype=torch.float32)


def _mask(cam, x, vis=None):
    uv, d = cam.project(x)
    return sphere_coverage(uv, sphere_radius_px(cam.fx, d, R_M), vis, cam.height, cam.width) > 0


def _random_net(seed=0, dtype=torch.float64, channels=8):
    torch.manual_seed(seed)
    net = BlendNet(channels).to(dtype)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(0.3 * torch.randn_like(p))
    return net


def test_distance_field_and_nearest_vectors_match_brute_force():
    rng = np.random.default_rng(1)
    H, W = 30, 40
    mask = np.zeros((H, W), bool)
    mask[5:9, 6:12] = True
    mask[20:26, 28:31] = True
    mask[rng.integers(0, H, 5), rng.integers(0, W, 5)] = True
    d = distance_field(torch.as_tensor(mask)).numpy()
    f = nearest_vectors(torch.as_tensor(mask), torch.float64).numpy()
    ii, jj = np.nonzero(mask)
    exact = 0
    for i in range(H):
        for j in range(W):
            dist2 = (ii - i) ** 2 + (jj - j) ** 2
            assert float(d[i, j]) ** 2 == pytest.approx(dist2.min(), abs=1e-3)   # exact: D² integer
            # Where the pixel and its 4 neighbours share one unique nearest pixel, −½∇D² is exact.
            nearest = lambda a, b: np.flatnonzero(((ii - a) ** 2 + (jj - b) ** 2) == ((ii - a) ** 2 + (jj - b) ** 2).min())
            k = nearest(i, j)
            if len(k) == 1 and 0 < i < H - 1 and 0 < j < W - 1 and all(
                    len(nearest(a, b)) == 1 and nearest(a, b)[0] == k[0]
                    for a, b in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1))):
                np.testing.assert_allclose(f[:, i, j], [jj[k[0]] - j, ii[k[0]] - i], atol=1e-3)
                exact += 1
    assert exact > 0.5 * H * W
    assert not nearest_vectors(torch.zeros(H, W, dtype=torch.bool)).any()
    assert torch.isinf(distance_field(torch.zeros(H, W, dtype=torch.bool))).all()


def test_distance_field_is_exact_and_the_same_on_every_call():
    """OpenCV's precise transform is off by about an ulp, by an amount that changes with its
    buffers' memory alignment: on windows of many widths the same mask gave two answers on
    alternate calls, and SPNets+perception replays of one recording parted within a process.
    distance_field rounds D² to the integer it is: exact against brute force (to 790 px at
    640×480) and bit-identical on calls made between allocations of every size."""
    rng = np.random.default_rng(3)
    for H, W in ((95, 142), (95, 101), (61, 133), (480, 640)):
        mask = np.zeros((H, W), bool)
        mask[2:H // 12, 2:W // 12] = True                                       # a blob and
        mask[rng.integers(0, H // 6, 6), rng.integers(0, W // 6, 6)] = True     # specks in a corner
        ii, jj = np.nonzero(mask)
        rows = np.arange(0, H, 13)
        exact = ((rows[:, None, None] - ii) ** 2 + (np.arange(W)[None, :, None] - jj) ** 2).min(-1)
        first = distance_field(torch.as_tensor(mask)).numpy()
        np.testing.assert_allclose(first[rows].astype(np.float64) ** 2, exact, rtol=3e-7, atol=0)
        field = nearest_vectors(torch.as_tensor(mask)).numpy()
        keep = []
        for k in range(8):
            keep.append(np.empty(int(rng.integers(1, 4000)), np.uint8))        # move the allocator
            np.testing.assert_array_equal(distance_field(torch.as_tensor(mask)).numpy(), first)
            np.testing.assert_array_equal(nearest_vectors(torch.as_tensor(mask)).numpy(), field)
    assert first.max() > 700


def test_window_gives_the_full_image_result(monkeypatch):
    cam = _camera()
    truth = _blob((0.0, 0.05, 0.0))
    obs = _mask(cam, truth)
    x = (truth + torch.tensor([0.03, 0.01, 0.0])).double()
    vis = visible(cam, x)
    net = _random_net()
    windowed = solve_perception(x, cam, vis, obs, net, radius_m=R_M)
    monkeypatch.setattr(P, "_crop", lambda o, uv, r, H, W: ((0, H, 0, W), uv))
    full = solve_perception(x, cam, vis, obs, net, radius_m=R_M)
    assert float(full.detach().abs().max()) > 1e-3
    torch.testing.assert_close(windowed, full, atol=1e-7, rtol=0)


def test_gradcheck_through_solve_perception():
    cam = _camera(48, 36)
    truth = _blob((0.0, 0.05, 0.0), half=0.012, spacing=0.008).double()
    obs = _mask(cam, truth)
    x0 = truth[::3] + torch.tensor([0.011, 0.004, 0.0], dtype=torch.float64)
    x0 = x0 + 1e-4 * torch.randn(x0.shape, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    vis = visible(cam, x0)
    vis[0] = False
    net = _random_net(channels=2)           # the same layers, narrower: 116 weights to perturb
    names = [n for n, _ in net.named_parameters()]
    params = tuple(p.detach().clone().requires_grad_(True) for p in net.parameters())

    class _With(torch.nn.Module):
        """The blending net evaluated with the parameter tensors ``ps`` (for gradcheck)."""

        def __init__(self, ps):
            super().__init__()
            self.ps = ps

        def forward(self, y):
            return torch.func.functional_call(net, dict(zip(names, self.ps)), (y,))

        @property
        def log_gain(self):
            return self.ps[names.index("log_gain")]

        @property
        def gain(self):
            return self.log_gain.exp()

    def f(x, *ps):
        return solve_perception(x, cam, vis, obs, _With(ps), radius_m=R_M)

    x = x0.clone().requires_grad_(True)
    out = f(x, *params)
    assert float(out[vis].abs().max()) > 1e-4 and bool((out[0] == 0).all())
    grads = torch.autograd.grad(out.square().sum(), (x, *params))
    assert all(float(g.abs().max()) > 0 for g in grads[:2]) and float(grads[names.index("log_gain") + 1].abs()) > 0
    assert torch.autograd.gradcheck(f, (x, *params), eps=1e-6, atol=1e-6, rtol=1e-4)


def test_occluded_particles_are_not_moved_and_labels_map_through_the_sort():
    cam = _camera()
    truth = _blob((0.0, 0.05, 0.0))
    obs_mask = _mask(cam, truth)
    x = truth + torch.tensor([0.03, 0.0, 0.0])
    # A wall between the camera and the right half of the blob.
    wall = sample_grid(lambda p: box(p, (0.02, 0.05, 0.002), (0.045, 0.05, 0.1)), (0.0, -0.02, 0.07),
                       (0.09, 0.12, 0.13), 0.002, 0.004, "wall")
    poses = torch.tensor([[0, 0, 0, 0, 0, 0, 1.0]])
    vis = visible(cam, x, [wall], poses)
    assert 0 < int(vis.sum()) < len(x)
    net = load_blend_net()
    d = solve_perception(x, cam, vis, obs_mask, net, radius_m=R_M)
    assert bool((d[~vis] == 0).all()) and float(d[vis].norm(dim=1).max()) > 0
    # The solver term: the tracker maps the observation's rows to labels, the step sorts them.
    model = FluidModel.create(H_K, spacing=SPACING, objects=[wall])
    tracker = SPNetsPerception(net)
    uv, depth = cam.project(x)
    tracker.correct(Observation(cam, obs_mask, x, torch.zeros_like(x), uv, depth, vis, None, 1.0, model, poses))
    term = tracker.terms()[0]
    state = make_state(x, poses=poses)
    state = dataclasses.replace(state, ids=torch.arange(100, 100 + len(x)))
    term.acceleration(model, state)                       # start of a step: labels resolved
    perm = torch.randperm(len(x), generator=torch.Generator().manual_seed(0))
    dp = term.position_delta(model, x[perm], state.ids[perm])
    assert bool((dp[~vis[perm]] == 0).all())
    moved = dp.norm(dim=1) > 0
    assert bool(vis[perm][moved].all()) and int(moved.sum()) > 0.5 * int(vis.sum())
    assert float(dp.norm(dim=1).max()) <= tracker.max_move * H_K + 1e-9


def test_mask_noise_around_a_matched_blob_does_not_pull_it(monkeypatch):
    """The model already draws what the camera sees, up to one-pixel slivers of ragged edge
    and specks: the disparity field must not chase them (with the shipped net F ≈ F_d, and
    without the opening every seen particle moved its full cap towards a sliver). A real
    uncovered region, wider than the noise, still pulls."""
    cam = _camera(320, 240)
    truth = _blob((0.0, 0.05, 0.0))
    clean = _mask(cam, truth)
    rng = np.random.default_rng(0)
    ragged = clean.numpy().copy()
    edge = np.argwhere(ragged & ~np.roll(ragged, 1, axis=1))          # left edge pixels
    for r, c in edge[rng.random(len(edge)) < 0.5]:
        ragged[r, c - 1] = True                                        # one-pixel bulges
    rows, cols = np.nonzero(clean.numpy())
    for _ in range(6):                                                 # specks beside the blob
        ragged[rng.integers(rows.min() - 10, rows.max() + 10), cols.max() + int(rng.integers(3, 12))] = True
    obs = torch.from_numpy(ragged)
    x = truth.double()
    vis = visible(cam, x)
    net = load_blend_net(dtype=torch.float64)
    moved = solve_perception(x, cam, vis, obs, net, radius_m=R_M, max_move=0.05 * H_K).norm(dim=1)
    monkeypatch.setattr(P, "NOISE_PX", 0.0)
    unopened = solve_perception(x, cam, vis, obs, net, radius_m=R_M, max_move=0.05 * H_K).norm(dim=1)
    assert float(unopened[vis].median()) > 0.5 * 0.05 * H_K           # the noise dragged the blob
    assert float(moved.max()) < 1e-3 * 0.05 * H_K
    monkeypatch.undo()
    wider = obs.clone()
    wider[rows.min():rows.min() + 8, cols.max() + 2:cols.max() + 10] = True   # an 8×8 px region the model misses
    pulled = solve_perception(x, cam, vis, wider, net, radius_m=R_M, max_move=0.05 * H_K).norm(dim=1)
    assert float(pulled.max()) > 0.5 * 0.05 * H_K


def test_solver_term_pulls_a_displaced_blob_onto_the_observation():
    cam = _camera(320, 240)
    truth = _blob((0.0, 0.05, 0.0))
    obs_mask = _mask(cam, truth)
    model = FluidModel.create(H_K, spacing=SPACING, dt=1 / 120, iterations=4, gravity=(0.0, 0.0, 0.0))
    tracker = SPNetsPerception()
    with_term = model.replace(terms=(tracker.terms()[0],))
    state = make_state(truth + torch.tensor([0.025, 0.01, 0.0]))
    ious, gaps = [], []
    with torch.no_grad():
        for k in range(12):
            vis = visible(cam, state.x)
            ious.append(iou(_mask(cam, state.x, vis), obs_mask))
            gaps.append(float((state.x.mean(0) - truth.mean(0)).norm()))
            uv, depth = cam.project(state.x)
            tracker.correct(Observation(cam, obs_mask, state.x, state.v, uv, depth, vis, None, 1.0, model,
                                        state.poses))
            state = step(with_term, state)
    ious.append(iou(_mask(cam, state.x), obs_mask))
    gaps.append(float((state.x.mean(0) - truth.mean(0)).norm()))
    open_state = make_state(truth + torch.tensor([0.025, 0.01, 0.0]))
    for _ in range(12):
        open_state = step(model, open_state)
    assert ious[0] < 0.3 and ious[-1] > ious[0] + 0.25, ious
    assert iou(_mask(cam, open_state.x), obs_mask) < ious[0] + 0.05
    assert gaps[-1] < 0.6 * gaps[0], gaps


def test_shipped_weights_load_and_bad_files_fail_clearly(tmp_path):
    state = torch.load(WEIGHTS, weights_only=True)
    assert isinstance(state, dict) and all(isinstance(v, torch.Tensor) for v in state.values())
    assert sum(v.numel() for v in state.values()) <= 50_000
    net = load_blend_net()
    assert 0 < float(net.gain) < 10
    assert net(torch.zeros(1, 1, 8, 8)).shape == (1, 1, 8, 8)
    bad = tmp_path / "corrupt.pt"
    bad.write_bytes(WEIGHTS.read_bytes()[:100])
    with pytest.raises(PerceptionWeightsError, match="corrupt.pt"):
        load_blend_net(bad)
    wrong = tmp_path / "wrong.pt"
    torch.save({"convs.0.weight": torch.zeros(4, 1, 5, 5)}, wrong)
    with pytest.raises(PerceptionWeightsError, match="does not match"):
        load_blend_net(wrong)
    nan = tmp_path / "nan.pt"
    torch.save({k: v * float("nan") for k, v in state.items()}, nan)
    with pytest.raises(PerceptionWeightsError, match="NaN"):
        load_blend_net(nan)
    with pytest.raises(PerceptionWeightsError, match="not found"):
        load_blend_net(tmp_path / "missing.pt")


@pytest.fixture(scope="module")
def pours(tmp_path_factory):
    """The generated pours, read back as the analysis reads them (the recording only)."""
    from liquidtwin.generate import generate
    from liquidtwin.recordings import read_recording
    d = tmp_path_factory.mktemp("pours")
    out = {}
    for seed in POUR_SEEDS:
        generate(POUR_SCENE, d / f"pour{seed}.mcap", seed=seed, quick=True, choices=POUR_CHOICES)
        out[seed] = read_recording(d / f"pour{seed}.mcap", images=False)
    return out


def test_closed_loop_sessions_track_generated_pours_better_than_open_loop(pours):
    """Over two realisations of the model's chaos (the first two ``realisations.SKINS``, the
    same recordings): SPNets+perception (the best tracker of the benchmark) beats open loop on
    average over the pours by its margin, and on every pour (its mean over the realisations).
    The warp field is not asserted here (POUR_MARGIN's comment)."""
    from liquidtwin.evaluate.replay import engine_for, replay
    gains = {m: [] for m in POUR_MARGIN}
    for skin in SKINS[:2]:
        for seed, rec in pours.items():
            scores = {}
            for mode in ("open_loop", *POUR_MARGIN):
                with realisation(skin):
                    eng = engine_for(rec, mode)
                    scores[mode] = replay(rec, eng).mean_iou()
                if mode != "open_loop":       # a correction keeps the liquid (open loop may splash some out)
                    assert eng.n_particles > 0.9 * eng._scene.state.x.shape[0], (skin, seed, mode)
            for m in POUR_MARGIN:
                gains[m].append(scores[m] - scores["open_loop"])
            print(f"skin {skin} h, seed {seed}: mean IOU " + ", ".join(f"{m} {v:.3f}" for m, v in scores.items()))
    for m, margin in POUR_MARGIN.items():
        assert np.mean(gains[m]) > margin, (m, gains[m])
    per_pour = np.mean(np.reshape(gains["spnets_perception"], (len(SKINS[:2]), len(pours))), 0)
    assert per_pour.min() > 0, gains


def test_a_spnets_perception_checkpoint_continues_bit_for_bit(pours):
    """A checkpoint taken mid-pour (the tracker's latest observation included) continues bit for bit."""
    from liquidtwin.evaluate.replay import engine_for, replay
    rec = pours[POUR_SEEDS[0]]
    a = engine_for(rec, "spnets_perception")
    replay(rec, a, frames=20)
    buf = io.BytesIO()
    torch.save(a.state_dict(), buf)
    buf.seek(0)
    b = engine_for(rec, "spnets_perception")
    b.load_state_dict(torch.load(buf, weights_only=True))
    stamps, masks = rec.masks[CAMERA]
    corrected = 0
    for i in range(20, 28):
        t = int(rec.pose_times_ns[i])
        for eng in (a, b):
            eng.advance((t - int(rec.pose_times_ns[0])) * 1e-9, dict(zip(rec.object_names, rec.poses[i])))
            j = int(np.searchsorted(stamps, t))
            if j < len(stamps) and stamps[j] == t:
                eng.correct(CAMERA, masks[j])
                corrected += 1
    assert corrected > 0
    np.testing.assert_array_equal(a.positions(), b.positions())


@pytest.mark.skipif(not fused.available(), reason="the C++ extension is not built")
def test_fast_fused_step_with_the_perception_term_matches_the_torch_reference():
    cam = _camera(320, 240)
    truth = _blob((0.0, 0.05, 0.0))
    obs_mask = _mask(cam, truth)
    x = truth + torch.tensor([0.02, 0.0, 0.0])
    out = {}
    for backend in ("fused", "torch"):
        model = FluidModel.create(H_K, spacing=SPACING, dt=1 / 120, iterations=4, gravity=(0.0, 0.0, 0.0),
                                  backend=backend)
        tracker = SPNetsPerception()
        state = make_state(x)
        vis = visible(cam, state.x)
        uv, depth = cam.project(state.x)
        tracker.correct(Observation(cam, obs_mask, state.x, state.v, uv, depth, vis, None, 1.0, model, state.poses))
        with torch.no_grad():
            s = step(model.replace(terms=tracker.terms()), state)
        out[backend] = s.by_id()[0]
    moved = (out["torch"] - x).norm(dim=1)
    assert float(moved.max()) > 1e-3
    torch.testing.assert_close(out["fused"], out["torch"], atol=1e-5, rtol=0)
