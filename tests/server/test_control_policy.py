"""The catching policy learned through SPNets (control.policy, thesis §8.3.4): the network's
layout, an observation that moves with the catcher, the rollout gradient against finite
differences, policy files (weights_only, bad files refused), the mirror-odd network, and the
shipped policy catching one of its training pours and its mirror image, never trained on (a
smaller fill than it was trained on), better than a catcher that stays put."""

import numpy as np
import pytest
import torch
from torch import nn

from liquidtwin.control.catch import MAX_SPEED, catching_setup, run_catch
from liquidtwin.control.policy import (HEIGHT, WIDTH, CatchPolicy, Demonstration, PolicyError, load_policy,
                                       parameter_count, place_catcher, rollout_loss, save_policy)
from liquidtwin.generate.world import model_for
from liquidtwin.scenes.fill import fill_container
from liquidtwin.scenes.liquid_level import held
from liquidtwin.sim import make_state, step


def _pour(motion, fill=0.2):
    setup = catching_setup(motion)
    model = model_for(setup)
    k = setup.index("source")
    state, _ = fill_container(model, torch.as_tensor(setup.poses_at(0.0)), k, setup.objects[k].model,
                              volume_ml=fill * dict(setup.fills)["source"], settle_s=0.3)
    return setup, model, state


def test_the_thesis_layout_and_the_pooled_one():
    thesis = CatchPolicy(pool=1)
    # conv 10·(9+1); linear (10·59·79 → 100); linear (100 → 1)
    assert parameter_count(thesis) == 10 * 10 + (10 * 59 * 79 + 1) * 100 + 101
    pooled = CatchPolicy()
    assert parameter_count(pooled) == 10 * 10 + (10 * 29 * 39 + 1) * 100 + 101
    assert float(pooled(torch.rand(1, HEIGHT, WIDTH)).detach()) == 0.0      # a fresh policy holds still
    out = pooled(torch.rand(3, HEIGHT, WIDTH) * 50)
    assert out.shape == (3,) and bool((out.abs() <= 1).all())
    with pytest.raises(PolicyError):
        CatchPolicy(pool=0)


def test_the_mirrored_network_is_odd_under_a_flip_and_survives_saving(tmp_path):
    torch.manual_seed(0)
    policy = CatchPolicy(mirror=True)
    nn.init.normal_(policy.out.weight, std=0.1)                   # not the hold-still start
    images = torch.rand(4, HEIGHT, WIDTH) * 5
    out = policy(images).detach()
    assert float(out.abs().min()) > 1e-4
    assert torch.allclose(policy(images.flip(-1)), -out, atol=1e-6)
    plain = CatchPolicy()
    plain.load_state_dict(policy.state_dict())
    assert not torch.allclose(plain(images.flip(-1)), -plain(images), atol=1e-3)   # not by accident
    save_policy(tmp_path / "m.pt", policy)
    back, meta = load_policy(tmp_path / "m.pt")
    assert meta["mirror"] is True and back.mirror
    assert torch.allclose(back(images), out, atol=5e-3)           # half-precision weights


def test_the_observation_moves_with_the_catcher():
    setup = catching_setup(0)
    policy = CatchPolicy()
    base = setup.poses_at(0.0)[setup.index("catcher")]
    x = torch.tensor([[base[0] + 0.05, base[1] + 0.3, base[2]], [base[0] - 0.1, base[1] + 0.05, base[2]]],
                     dtype=torch.float64)
    q = torch.tensor([base[0]], dtype=torch.float64)
    image = policy.observe(x, q, setup)
    shifted = policy.observe(x + torch.tensor([0.2, 0.0, 0.0], dtype=torch.float64), q + 0.2, setup)
    assert torch.allclose(image, shifted, atol=1e-9)
    assert image.shape == (HEIGHT, WIDTH)
    # the particle right of and above the catcher is drawn right of centre and in the upper half
    rows, cols = np.nonzero(image.numpy() > 0.5)
    assert rows.size and cols.max() > WIDTH / 2 and rows.min() < HEIGHT / 2
    assert not torch.allclose(image, policy.observe(x, q + 0.1, setup))


def test_the_rollout_gradient_matches_finite_differences():
    setup, model, state = _pour(3, fill=0.1)
    s, i, k = state, 0, setup.index("source")
    with torch.no_grad():                           # into the pour: a tenth of the liquid has left
        while held(model, s, k, setup.objects[k].model)[0].mean() > 0.9 and i < 300:
            s = step(model, s, torch.as_tensor(setup.poses_at((i + 1) * model.dt)).to(s.x))
            i += 1
    s64 = make_state(*s.by_id(), poses=s.poses.double(), dtype=torch.float64, t=s.t)
    torch.manual_seed(0)
    policy = CatchPolicy().double()
    with torch.no_grad():
        policy.out.weight.mul_(20.0)                # outputs away from 0 so the rollout moves
    # the state before step i, no predicted landing
    demo = Demonstration(setup, [None] * i + [s64], np.zeros(i + 1), np.full(i + 1, np.nan))
    x0 = float(setup.poses_at(0.0)[setup.index("catcher")][0]) + 0.02

    def loss():
        return rollout_loss(policy, model, demo, i, x0, 3)

    L = loss()
    assert i < 300 and float(L.detach()) > 1e-3                          # the landing-distance regime, not "hold still"
    params = [("out.bias", policy.out.bias, (0,)), ("hidden.weight", policy.hidden.weight, (3, 7)),
              ("conv.bias", policy.conv.bias, (2,))]
    grads = torch.autograd.grad(L, [p for _, p, _ in params])
    eps = 1e-5
    for (name, p, idx), g in zip(params, grads):
        with torch.no_grad():
            p[idx] += eps
            up = float(loss())
            p[idx] -= 2 * eps
            down = float(loss())
            p[idx] += eps
        fd = (up - down) / (2 * eps)
        print(f"\n∂L/∂{name}{list(idx)}: autograd {float(g[idx]):.6g}, finite differences {fd:.6g}")
        assert float(g[idx]) == pytest.approx(fd, rel=2e-3, abs=1e-10)
    assert float(grads[0].abs()) > 0


def test_placing_the_catcher_carries_its_liquid():
    setup, model, state = _pour(0, fill=0.3)
    kc, ks = setup.index("catcher"), setup.index("source")
    s = state
    x = s.x.clone()                                 # pour the source's liquid into the catcher by hand:
    x[:, 0] += float(s.poses[kc, 0] - s.poses[ks, 0])         # the same column …
    x[:, 1] += float(s.poses[kc, 1] - s.poses[ks, 1])         # … the catcher's height
    s = make_state(x, s.v, poses=s.poses, t=s.t)
    inside = held(model, s, kc, setup.objects[kc].model)[0]
    assert inside.mean() > 0.9
    moved = place_catcher(setup, model, s, float(s.poses[kc, 0]) + 0.07)
    assert float(moved.poses[kc, 0] - s.poses[kc, 0]) == pytest.approx(0.07)
    assert torch.equal(moved.poses[ks], s.poses[ks])
    d = (moved.x - s.x).numpy()
    assert np.allclose(d[inside, 0], 0.07, atol=1e-6) and np.allclose(d[~inside], 0) and np.allclose(d[:, 1:], 0)
    assert np.array_equal(held(model, moved, kc, setup.objects[kc].model)[0], inside)


def test_policy_files_round_trip_and_bad_ones_are_refused(tmp_path):
    policy = CatchPolicy()
    torch.nn.init.normal_(policy.out.weight, std=0.3)
    path = save_policy(tmp_path / "p.pt", policy, {"motions": [0, 1]})
    back, meta = load_policy(path)
    assert meta["motions"] == [0, 1] and meta["pool"] == 2
    for (k, a), b in zip(policy.state_dict().items(), back.state_dict().values()):   # half precision on disk
        assert b.dtype == torch.float32 and torch.equal(b, a.half().float()), k
    image = torch.rand(2, HEIGHT, WIDTH) * 3
    out = policy.eval()(image)
    assert float(out.abs().min()) > 1e-3 and torch.allclose(back(image), out, atol=2e-3)
    with pytest.raises(PolicyError, match="no catching policy"):
        load_policy(tmp_path / "missing.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a torch file")
    with pytest.raises(PolicyError, match="readable"):
        load_policy(tmp_path / "junk.pt")
    torch.save({"format": "something else"}, tmp_path / "other.pt")
    with pytest.raises(PolicyError, match="is not a"):
        load_policy(tmp_path / "other.pt")
    torch.save({"format": "liquidtwin-catch-policy-1", "meta": '{"pool": 4, "hidden": 100}',
                "state_dict": {"conv.weight": torch.zeros(1)}}, tmp_path / "bad.pt")
    with pytest.raises(PolicyError, match="unreadable"):
        load_policy(tmp_path / "bad.pt")


@pytest.mark.parametrize("motion, trained", [(2, True), (5, False)])
def test_the_shipped_policy_catches_a_pour(motion, trained):
    """Motion 2 is a training motion; motion 5 is its mirror image (pours towards +x, the lip
    drifting the other way), never seen in training: the shipped network is mirror-odd."""
    policy, meta = load_policy()
    assert (motion in meta["motions"]) == trained and meta["pool"] == 2 and meta["mirror"]
    setup, model, state = _pour(motion)
    r = run_catch(setup, model, state, policy=policy)
    s = state
    with torch.no_grad():                           # the same pour, the catcher left where it starts
        for i in range(len(r.xs)):
            s = step(model, s, torch.as_tensor(setup.poses_at((i + 1) * model.dt)).to(s.x))
    kc = setup.index("catcher")
    still = float(held(model, s, kc, setup.objects[kc].model)[0].sum()) / s.x.shape[0]
    print(f"\nmotion {motion}: policy caught {r.caught:.3f} (still catcher {still:.3f}), catcher "
          f"{100 * r.xs[0]:.1f} → {100 * r.xs[-1]:.1f} cm, {1e3 * r.update_s:.1f} ms per step")
    assert r.left_source > 0.9
    assert np.abs(np.diff(np.concatenate([[setup.poses_at(0.0)[kc][0]], r.xs]))).max() <= MAX_SPEED * model.dt + 1e-9
    assert r.caught > 0.85 and r.caught > still + 0.3, (r.caught, still)


def test_command_line_errors_are_clear(tmp_path):
    import subprocess
    import sys

    def run(*args):
        return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=120)

    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "catching", "--controller", "policy",
            "--policy", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "no catching policy file" in r.stderr
    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "pouring", "--targets", "70",
            "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "each in (0, 60)" in r.stderr
    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "pouring", "--full", "--targets", "310",
            "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "each in (0, 300)" in r.stderr          # the full-size cup holds 300 ml
    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "pouring", "--targets", "10",
            "--approach-rate", "-1", "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "--approach-rate: approach_rate must be a positive number" in r.stderr
    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "pouring", "--targets", "10",
            "--cup-scale", "1.5", "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "--cup-scale must be in (0, 1]" in r.stderr
    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "pouring", "--served", "30",
            "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "--served runs the plate and catching tasks" in r.stderr
    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "catching", "--served", "30", "--controller",
            "policy", "--policy", str(tmp_path / "mine.pt"), "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "runs the shipped catching policy" in r.stderr
    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "plate", "--served", "-5",
            "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "--served takes frames per second > 0" in r.stderr
    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "plate", "--lookahead", "-1",
            "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "--lookahead takes seconds >= 0" in r.stderr
    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "catching", "--lookahead", "1",
            "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "--lookahead sets the offline plate and pouring MPC's loss" in r.stderr
    r = run("-m", "liquidtwin.cli", "evaluate", "control", "--scene", "plate", "--served", "30", "--lookahead", "1",
            "--out", str(tmp_path / "out"))
    assert r.returncode != 0 and "--lookahead sets the offline plate and pouring MPC's loss" in r.stderr
    r = run("-m", "liquidtwin.control.train_policy", "--out", str(tmp_path / "p.pt"), "--motions", "9")
    assert r.returncode == 2 and "source motions 0-7" in r.stderr
    r = run("-m", "liquidtwin.control.train_policy", "--help")
    assert r.returncode == 0 and "--iterations" in r.stdout
    assert not (tmp_path / "out").exists() and not (tmp_path / "p.pt").exists()
