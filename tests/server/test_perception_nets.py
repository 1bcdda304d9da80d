"""Perception networks, inputs, flow and model files (issue 8): shapes, streaming state,
weights_only round trips and clear errors; flow against a known image shift."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from liquidtwin.perception import (FLOW_SCALE_PX, FUSIONS, INPUTS, KINDS, FrameEncoder, PerceptionInputError,
                                   PerceptionModelError, build_model, encode_flow, farneback, load_model,
                                   parameter_count, save_model)

H, W = 32, 40


def _grid():
    return [(k, i, f) for k in KINDS for i in INPUTS for f in FUSIONS if f == "early" or "_" in i]


@pytest.mark.parametrize("kind,input_type,fusion", _grid())
def test_every_network_maps_a_sequence_to_per_pixel_logits(kind, input_type, fusion):
    net = build_model(kind, input_type, fusion)
    c = sum(INPUTS[input_type])
    assert net.in_channels == c
    y = net(torch.rand(2, 3, c, H, W))
    assert y.shape == (2, 3, 1, H, W)
    assert torch.isfinite(y).all()
    assert parameter_count(net) * 4 < 5e6            # the ≤ 5 MB budget of a shipped model


@pytest.mark.parametrize("kind", KINDS)
def test_streaming_step_by_step_equals_the_sequence_forward(kind):
    torch.manual_seed(0)
    net = build_model(kind, "grey_flow", "late").eval()
    seq = torch.rand(2, 5, 4, H, W)
    with torch.no_grad():
        whole = net(seq)
        state = net.initial_state(2, H, W)
        steps = []
        for t in range(5):
            y, state = net.step(seq[:, t], state)
            steps.append(y)
    torch.testing.assert_close(torch.stack(steps, 1), whole, rtol=1e-5, atol=1e-5)


def _reach(net, t_probe: int, t_change: int) -> float:
    """How much output t_probe moves when frame t_change is replaced."""
    torch.manual_seed(1)
    seq = torch.rand(1, t_probe + 1, 1, H, W)
    other = seq.clone()
    other[:, t_change] = torch.rand(1, H, W)
    with torch.no_grad():
        return float((net(seq)[:, t_probe] - net(other)[:, t_probe]).abs().max())


def test_memory_fcn_none_mf_fcn_a_window_lstm_fcn_the_whole_past():
    torch.manual_seed(0)
    fcn, mf, lstm = (build_model(k, "grey").eval() for k in ("fcn", "mf_fcn", "lstm_fcn"))
    assert _reach(fcn, 2, 0) == 0.0
    assert _reach(mf, 2, 0) > 1e-6                    # frames=4: t−2 is inside the window
    assert _reach(mf, 6, 0) == 0.0                    # … t−6 is not
    assert _reach(lstm, 6, 0) > 1e-7                  # the recurrent state carries it


def test_state_of_another_size_is_refused():
    net = build_model("lstm_fcn", "grey")
    state = net.initial_state(1, H, W)
    with pytest.raises(ValueError, match="new state"):
        net.step(torch.rand(1, 1, 48, 64), state)
    with pytest.raises(ValueError, match="multiple of 4"):
        net(torch.rand(1, 2, 1, 30, 40))
    with pytest.raises(ValueError, match="expected input"):
        net(torch.rand(1, 2, 3, H, W))


def test_unknown_kind_input_or_fusion_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown detector kind"):
        build_model("unet")
    with pytest.raises(ValueError, match="unknown input type"):
        build_model("fcn", "depth")
    with pytest.raises(ValueError, match="unknown fusion"):
        build_model("fcn", "grey_flow", "middle")


def test_model_file_round_trip_is_bit_exact(tmp_path):
    torch.manual_seed(3)
    net = build_model("mf_fcn", "rgb_flow", "late", frames=3).eval()
    path = save_model(tmp_path / "m.pt", net, {"note": "test"})
    back, meta = load_model(path)
    assert meta["kind"] == "mf_fcn" and meta["note"] == "test" and back.frames == 3
    for (k, a), (_, b) in zip(net.state_dict().items(), back.state_dict().items()):
        assert torch.equal(a, b), k
    x = torch.rand(1, 4, 6, H, W)
    with torch.no_grad():
        assert torch.equal(net(x), back(x))


def test_corrupt_foreign_or_mismatched_model_files_give_clear_errors(tmp_path):
    net = build_model("fcn", "grey")
    good = save_model(tmp_path / "good.pt", net)
    bad = tmp_path / "truncated.pt"
    bad.write_bytes(good.read_bytes()[:200])
    with pytest.raises(PerceptionModelError, match="not a readable"):
        load_model(bad)
    torch.save({"weights": torch.zeros(3)}, tmp_path / "foreign.pt")
    with pytest.raises(PerceptionModelError, match="is not a liquidtwin.perception"):
        load_model(tmp_path / "foreign.pt")
    blob = torch.load(good, weights_only=True)
    blob["meta"] = blob["meta"].replace('"grey"', '"rgb"')      # weights for 1 input channel, meta says 3
    torch.save(blob, tmp_path / "mismatch.pt")
    with pytest.raises(PerceptionModelError, match="do not match"):
        load_model(tmp_path / "mismatch.pt")
    blob["meta"] = blob["meta"].replace('"fcn"', '"transformer"')
    torch.save(blob, tmp_path / "kind.pt")
    with pytest.raises(PerceptionModelError, match="unknown detector kind"):
        load_model(tmp_path / "kind.pt")
    with pytest.raises(PerceptionModelError, match="no detector model file"):
        load_model(tmp_path / "absent.pt")


def _texture(h=96, w=128, seed=0):
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur((rng.random((h, w)) * 255).astype(np.uint8), (0, 0), 2.0)


def test_farneback_flow_of_a_shifted_texture_points_along_the_shift():
    a = _texture()
    b = np.roll(a, 3, axis=1)                          # content moves +3 px in x
    planes = encode_flow(farneback(a, b))
    inner = (slice(20, -20), slice(20, -20))
    sin, cos, mag = (p[inner] for p in planes)
    assert np.median(mag) * FLOW_SCALE_PX == pytest.approx(3.0, abs=0.3)
    assert np.median(cos) > 0.99 and abs(np.median(sin)) < 0.05
    # and downwards: angle +90° in image coordinates (y down)
    planes = encode_flow(farneback(a, np.roll(a, 2, axis=0)))
    assert np.median(planes[0][inner]) > 0.99


def test_frame_encoder_channels_first_frame_and_bad_frames():
    frames = [cv2.cvtColor(np.roll(_texture(), 2 * k, axis=1), cv2.COLOR_GRAY2RGB) for k in range(3)]
    x = FrameEncoder("rgb_flow").sequence(frames)
    assert x.shape == (3, 6, 96, 128) and x.dtype == np.float32
    assert np.all(x[0, 5] == 0) and np.all(x[0, 4] == 1)          # first frame: zero flow (cos 1)
    assert np.median(x[2, 5]) * FLOW_SCALE_PX == pytest.approx(2.0, abs=0.3)
    g = FrameEncoder("grey", size=(64, 48))(frames[0])
    assert g.shape == (1, 48, 64) and 0 <= g.min() and g.max() <= 1
    enc = FrameEncoder("grey_flow")
    enc(frames[0])
    with pytest.raises(PerceptionInputError, match="size changed"):
        enc(frames[0][:64])
    with pytest.raises(PerceptionInputError, match="uint8"):
        enc(frames[0].astype(np.float32))
    with pytest.raises(PerceptionInputError, match="RGB image"):
        enc(frames[0][..., 0])
