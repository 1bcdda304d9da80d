"""``liquidtwin perception register`` on image files (issue 8): a heated-chessboard pair
written as a 16-bit thermal PNG (centi-kelvin) and a colour PNG, the known affine map
recovered through the command line; clear errors for bad arguments."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from liquidtwin.cli import main
from liquidtwin.perception import apply_affine, load_model, synthetic_board_pair


def test_register_recovers_a_known_map_from_image_files(tmp_path, capsys):
    rng = np.random.default_rng(4)
    true = np.array([[1.45, 0.08, 31.0], [-0.06, 1.5, 22.0]])
    colour, thermal, _, t_corners = synthetic_board_pair(rng, (7, 5), true)
    cv2.imwrite(str(tmp_path / "t.png"), np.round((thermal + 273.15) * 100).astype(np.uint16))
    cv2.imwrite(str(tmp_path / "c.png"), cv2.cvtColor(colour, cv2.COLOR_RGB2BGR))
    out = tmp_path / "affine.json"
    assert main(["perception", "register", "--thermal", str(tmp_path / "t.png"), "--colour",
                 str(tmp_path / "c.png"), "--pattern", "7x5", "--out", str(out)]) == 0
    assert "RMS residual" in capsys.readouterr().out
    fitted = np.array(json.loads(out.read_text())["affine"])
    err = np.abs(apply_affine(fitted, t_corners) - apply_affine(true, t_corners)).max()
    assert err < 0.5, err


def test_register_errors_are_clear(tmp_path):
    with pytest.raises(SystemExit, match="same number"):
        main(["perception", "register", "--thermal", "a.png", "b.png", "--colour", "c.png"])
    with pytest.raises(SystemExit, match="COLSxROWS"):
        main(["perception", "register", "--thermal", "a.png", "--colour", "c.png", "--pattern", "7"])
    with pytest.raises(SystemExit, match="cannot read"):
        main(["perception", "register", "--thermal", str(tmp_path / "none.png"), "--colour", "c.png"])
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((60, 80), 128, np.uint8))
    with pytest.raises(SystemExit, match="register"):
        main(["perception", "register", "--thermal", str(blank), "--colour", str(blank)])


def test_evaluate_perception_end_to_end_on_a_tiny_dataset(tmp_path, capsys):
    """Dataset generated on the spot (1 training + 1 test pour), two tiny trainings (the
    LSTM-FCN starts from the FCN), the table, JSON and figures."""
    out = tmp_path / "eval"
    assert main(["evaluate", "perception", "--data", str(tmp_path / "data"), "--out", str(out),
                 "--models", "fcn/grey_flow/early,lstm_fcn/grey_flow/early", "--train-seqs", "1",
                 "--test-seqs", "1", "--crop-iterations", "4", "--full-iterations", "2", "--jobs", "1",
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "baseline (flow, §4.5.3)" in text and "lstm_fcn: AUC %" in text
    doc = json.loads((out / "perception.json").read_text())
    manifest = json.loads((tmp_path / "data" / "dataset.json").read_text())
    assert [e["source"] for e in manifest["test"]] == ["mug"] and manifest["train"][0]["source"] in ("cup", "bottle")
    by = {r["kind"]: r for r in doc["results"]}
    assert by["fcn"]["init"] is None and by["lstm_fcn"]["init"] == "fcn-grey_flow-early.pt"
    for r in [*doc["results"], doc["baseline"]]:
        for split in ("train", "test"):
            aucs = [r[split][str(s)] for s in (0, 1, 2, 4)]
            assert all(0 <= a <= 1 for a in aucs) and aucs == sorted(aucs)     # slack only helps
    assert (out / "pr_curves.png").stat().st_size > 0 and (out / "detections.png").stat().st_size > 0
    assert "selected_step" not in by["fcn"] and not (out / "selection.png").exists()
    fcn_meta = load_model(out / "models" / "fcn-grey_flow-early.pt")[1]
    assert fcn_meta["selected_step"] is None and fcn_meta["size"] == [160, 120]    # a detector a session can run
    with pytest.raises(SystemExit, match="calibration pours"):      # nothing held out to choose on
        main(["evaluate", "perception", "--data", str(tmp_path / "data"), "--out", str(out), "--select-every", "2"])
    with pytest.raises(SystemExit, match="KIND/INPUT/FUSION"):
        main(["evaluate", "perception", "--data", str(tmp_path / "data"), "--models", "unet/rgb/early"])
    with pytest.raises(SystemExit, match="--augment: unknown augmentation"):
        main(["evaluate", "perception", "--data", str(tmp_path / "data"), "--augment", "flip,jitter"])
    assert doc["augment"] == ""


def test_calibration_split_resumes_the_dataset_and_sets_the_threshold(tmp_path, capsys):
    """`perception data --calib` adds held-out pours of the training containers without
    regenerating the others; `train` and `calibrate` pick the threshold there, and it is the
    F1-best one of a brute-force sweep over the calibration frames."""
    from liquidtwin.perception.data import TRAIN, load_split
    from liquidtwin.perception.train import detect, encode_clips
    data = tmp_path / "data"
    args = ["perception", "data", "--out", str(data), "--train", "1", "--test", "1", "--no-progress"]
    assert main([*args, "--calib", "0"]) == 0
    first = json.loads((data / "dataset.json").read_text())
    stamp = (data / "train" / "000.mcap").stat().st_mtime_ns
    assert main([*args, "--calib", "1"]) == 0
    second = json.loads((data / "dataset.json").read_text())
    assert second["train"] == first["train"] and second["test"] == first["test"]
    assert (data / "train" / "000.mcap").stat().st_mtime_ns == stamp          # kept, not regenerated
    (cal,) = second["calib"]
    assert cal["source"] in TRAIN["source"] and cal["target"] in TRAIN["target"] and cal["seed"] != first["train"][0]["seed"]

    model = tmp_path / "fcn.pt"
    assert main(["perception", "train", "--data", str(data), "--kind", "fcn", "--crop-iterations", "3",
                 "--full-iterations", "2", "--out", str(model), "--no-progress"]) == 0
    net, meta = load_model(model)
    assert meta["threshold_from"] == {"split": "calib", "pours": 1}
    clips = load_split(data, "calib")
    probs = np.concatenate([detect(net, x) for x in encode_clips(clips, meta["input_type"])]).ravel()
    truth = np.concatenate([c.masks for c in clips]).ravel()

    def f1(t):
        tp = np.count_nonzero((probs >= t) & truth)
        return 2 * tp / max(np.count_nonzero(probs >= t) + np.count_nonzero(truth), 1)
    brute = max(f1(t) for t in np.linspace(0, 1, 201))
    assert f1(meta["threshold"]) >= brute - 0.01

    chosen = tmp_path / "chosen.pt"                   # training length chosen on the same pours
    assert main(["perception", "train", "--data", str(data), "--kind", "fcn", "--crop-iterations", "3",
                 "--full-iterations", "2", "--select-every", "2", "--augment", "colour,flip", "--out", str(chosen),
                 "--no-progress"]) == 0
    assert "best 0 px AUC on the 1 calibration pours" in capsys.readouterr().out
    chosen_meta = load_model(chosen)[1]
    assert chosen_meta["selected_step"] in (2, 4, 5) and chosen_meta["trained"]["augment"] == "flip,colour"
    with pytest.raises(SystemExit, match="--augment: unknown augmentation rotate"):
        main(["perception", "train", "--data", str(data), "--augment", "rotate", "--out", str(tmp_path / "x.pt")])

    capsys.readouterr()                              # score: the AUCs train printed, read back without training
    out_json = tmp_path / "score.json"
    assert main(["perception", "score", str(model), "--data", str(data), "--splits", "train", "test",
                 "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    assert "fcn/grey_flow/early on" in text and "test   1 pours:" in text and "flow baseline" in text
    scored = json.loads(out_json.read_text())["splits"]
    assert scored["test"]["auc"] == pytest.approx(meta["auc"]["test"]) and scored["train"]["auc"] == pytest.approx(meta["auc"]["train"])
    assert 0 <= scored["test"]["baseline"]["0"] <= scored["test"]["baseline"]["4"] <= 1
    with pytest.raises(SystemExit, match="not a perception dataset"):
        main(["perception", "score", str(model), "--data", str(tmp_path)])

    assert main(["perception", "calibrate", str(model), "--data", str(data), "--out", str(tmp_path / "c.pt")]) == 0
    assert "F1-best on 1 calibration pours" in capsys.readouterr().out
    _, meta2 = load_model(tmp_path / "c.pt")
    assert meta2["threshold"] == pytest.approx(meta["threshold"]) and meta2["threshold_from"]["pours"] == 1

    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "dataset.json").write_text(json.dumps({**first, "calib": []}))
    with pytest.raises(SystemExit, match="no calibration pours"):
        main(["perception", "calibrate", str(model), "--data", str(bare)])
    with pytest.raises(SystemExit, match="chooses on the calibration pours"):
        main(["perception", "train", "--data", str(bare), "--select-every", "2", "--out", str(tmp_path / "x.pt")])
