"""Discrepancy discovery, blind: the generator plants an effect and writes the truth to a
sidecar; the analysis gets the recording path only; the test then opens the sidecar and
compares. The small, fast subset of ``liquidtwin evaluate discrepancy`` that passes today:
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

import numpy as np
import pytest

from liquidtwin.cli import main as cli_main
from liquidtwin.discrepancy import Options, analyse
from liquidtwin.generate import generate

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")

#: (planted effect or None, seed): quick pour_hold, cup 90 % full, target drawn by the seed.
CASES = {"none": (None, 7), "time_offset": ("time_offset", 9)}


def upper_range_value(name: str, seed: int) -> float:
    """A magnitude in the upper 40 % of one of the effect's realistic ranges (sign by the seed)."""
    from liquidtwin.generate.effects import EFFECTS
    rng = np.random.default_rng([seed, 6])
    ranges = EFFECTS[name].ranges
    lo, hi = ranges[int(rng.integers(len(ranges)))]
    far, near = (lo, hi) if abs(lo) > abs(hi) else (hi, lo)        # the larger magnitude end
    return float(far + rng.uniform(0.0, 0.4) * (near - far))


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    d = tmp_path_factory.mktemp("blind")
    out = {}
    for name, (effect, seed) in CASES.items():
        path = d / f"{name}.mcap"
        effects = [(effect, upper_range_value(effect, seed))] if effect else []
        generate("pour_hold", path, effects=effects, seed=seed, quick=True, choices={"source": "cup", "fraction": 0.9})
        out[name] = path
    return out


def _truth(path):
    """The sidecar — read only after the analysis, to score it."""
    return json.loads(path.with_suffix(".truth.json").read_text())["effect"]


def _candidate(report, name):
    return next(c for c in report["candidates"] if c["name"] == name)


def test_nothing_hidden_is_none_and_the_cli_writes_the_report(recordings, tmp_path):
    out = tmp_path / "report"
    code = cli_main(["discrepancy", str(recordings["none"]), "--out", str(out), "--no-progress",
                     "--candidates", "drag", "camera_offset", "--top", "2"])
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
    assert report["model"]["name"] == "none" and report["extended"]["name"] == "none"
    assert json.loads((out / "model.json").read_text())["name"] == "none"
    for f in ("report.md", "iou_over_time.png", "residual_maps.png", "candidates.png"):
        assert (out / f).stat().st_size > 1000
    assert "Decision: `none`" in (out / "report.md").read_text()


def _check(path, candidates, report):
    truth = _truth(path)
    assert report["decision"] == truth["name"], (report["decision"], truth,
                                                 [(c["name"], c["heldout_gain"], c.get("null_gains"))
                                                  for c in report["candidates"]])
    c = _candidate(report, truth["name"])
    assert c["heldout_gain"]["ci95"][0] > 0
    assert report["extended"]["heldout_loss"] < report["baseline"]["heldout_loss"]
    return truth, c


def test_time_offset_is_told_from_camera_offset(recordings):
    path = recordings["time_offset"]
    report = analyse([path], options=Options(candidates=("time_offset", "camera_offset"), top=2))
    truth, c = _check(path, ("time_offset", "camera_offset"), report)
    assert abs(c["value"] - truth["value"]) <= 0.25 * abs(truth["value"])
