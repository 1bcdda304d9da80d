"""Discrepancy discovery, blind: the generator plants an effect and writes the truth to a
sidecar; the analysis gets the recording path only; the test then opens the sidecar and
compares. The small, fast subset (this file and
``test_discrepancy_blind_offset.py``) of ``liquidtwin evaluate discrepancy`` that passes today:
nothing hidden → ``none`` (through the CLI, checking the report's contract), and a time
offset told from a camera offset (the cheap observation pair; candidates restricted to the
pair so it fits in CI).

The other pairs the issue names are NOT asserted here because the analysis does not yet get
them right on these quick 1.9-second pours (measured, commit of this file, upper-range
magnitudes as below): drag 2.8 1/m (seed 8) ranked first against viscosity but its held-out
interval touched zero → ``none``; camera offset 2.2° (seed 10) → ``none``; fill error +29 %
(seed 11) → ``unexplained``. The full-range benchmark (``liquidtwin evaluate discrepancy``)
reports the confusion matrix.

Magnitudes are drawn (seeded) from the upper 40 % of each effect's realistic range."""

import json

import pytest
from blind_cases import candidate as _candidate
from blind_cases import record
from blind_cases import truth as _truth

from liquidtwin.cli import main as cli_main

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    return {"none": record("none", tmp_path_factory.mktemp("blind"))}


def test_nothing_hidden_is_none_and_the_cli_writes_the_report(recordings, tmp_path):
    out = tmp_path / "report"
    code = cli_main(["discrepancy", str(recordings["none"]), "--out", str(out), "--no-progress",
                     "--candidates", "drag", "fill_error", "camera_offset", "--top", "2", "--fill-fit", "mass"])
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    assert _truth(recordings["none"]) is None
    assert report["decision"] == "none"
    for key in ("decision", "candidates", "baseline", "extended", "split"):
        assert key in report
    assert [c["name"] for c in report["candidates"]] == sorted(
        (c["name"] for c in report["candidates"]), key=lambda n: -_candidate(report, n)["heldout_gain"]["mean"])
    for c in report["candidates"]:
        lo, hi = c["heldout_gain"]["ci95"]
        assert lo <= c["heldout_gain"]["mean"] <= hi and set(c) >= {"name", "params", "heldout_gain", "evidence"}
    assert report["split"]["fit_frames"] > 0 and report["split"]["held_out_frames"] > 0
    # the fill error's search minimised the liquid's amount mismatch; its trace keeps both values
    fill = _candidate(report, "fill_error")
    assert fill["fit_objective"] == "mass" and _candidate(report, "drag")["fit_objective"] == "loss"
    assert fill["trace"] and all({"fit_loss", "mass_mismatch"} <= set(t) for t in fill["trace"])
    assert min(fill["trace"], key=lambda t: t["mass_mismatch"])["params"]["value"] == pytest.approx(fill["best_tried"])
    assert report["model"]["name"] == "none" and report["extended"]["name"] == "none"
    assert json.loads((out / "model.json").read_text())["name"] == "none"
    for f in ("report.md", "iou_over_time.png", "residual_maps.png", "candidates.png"):
        assert (out / f).stat().st_size > 1000
    md = (out / "report.md").read_text()
    assert "Decision: `none`" in md and "shorter than one frame period of the camera is not declared" in md
    assert report["frame_s"] == pytest.approx(1 / 30, rel=0.01)          # the generator's 30 Hz masks
