"""bench/tracking_paired.py: two tracking runs compared pour by pour, on hand-made results
whose differences are known."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.tracking_paired import paired  # noqa: E402


def _run(warp: list[float], masks: list[float]) -> dict:
    cases = []
    for i, (w, m) in enumerate(zip(warp, masks)):
        detector = {"iou": [m, m, 0.9], "observed_px": [60, 80, 10]}       # the last frame is too small to count
        cases.append({"recording": f"pour{i}.mcap", "mean_iou": {"warp_field/detected": w, "ceiling": 0.7},
                      "detector": detector})
    return {"cases": cases}


def test_differences_are_paired_by_recording_and_the_interval_covers_them():
    a = _run([0.2, 0.3, 0.1, 0.4], [0.1, 0.1, 0.2, 0.2])
    b = _run([0.25, 0.35, 0.15, 0.45], [0.1, 0.3, 0.2, 0.4])
    b["cases"] = b["cases"][::-1] + [{"recording": "only-in-b.mcap", "mean_iou": {"warp_field/detected": 0.0}}]
    rows = {r["column"]: r for r in paired(a, b)}
    assert set(rows) == {"warp_field/detected", "detector mask"}             # ceiling is not a tracker
    w, m = rows["warp_field/detected"], rows["detector mask"]
    assert w["pours"] == 4 and w["mean_diff"] == pytest.approx(0.05) and w["b_better"] == 4
    assert w["low"] == pytest.approx(0.05) and w["high"] == pytest.approx(0.05)  # every pour +0.05
    assert m["mean_diff"] == pytest.approx(0.1) and m["b_better"] == 2
    assert m["low"] < 0.1 < m["high"] and m["low"] >= 0.0 - 1e-12 and m["high"] <= 0.2 + 1e-12


def test_script_prints_the_table_and_refuses_unrelated_runs(tmp_path):
    fa, fb = tmp_path / "a.json", tmp_path / "b.json"
    fa.write_text(json.dumps(_run([0.2, 0.3], [0.1, 0.2])))
    fb.write_text(json.dumps(_run([0.1, 0.2], [0.1, 0.2])))
    out = subprocess.run([sys.executable, str(ROOT / "bench" / "tracking_paired.py"), str(fa), str(fb)],
                         capture_output=True, text=True, check=True).stdout
    assert "warp_field/detected" in out and "-10.00" in out
    other = _run([0.2], [0.1])
    other["cases"][0]["recording"] = "elsewhere.mcap"
    fb.write_text(json.dumps(other))
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "tracking_paired.py"), str(fa), str(fb)],
                       capture_output=True, text=True)
    assert r.returncode != 0 and "share no recording" in r.stderr


def test_runs_over_two_data_directories_pair_by_case_unless_their_ceilings_differ():
    a, b = _run([0.2, 0.3], [0.1, 0.1]), _run([0.3, 0.4], [0.1, 0.1])
    for i, c in enumerate(b["cases"]):
        c["recording"] = f"/elsewhere/pour{i}.mcap"                       # the same cases, another --data
    assert {r["column"]: r["pours"] for r in paired(a, b)}["warp_field/detected"] == 2
    b["cases"][1]["mean_iou"]["ceiling"] = 0.5                             # not the same recording after all
    with pytest.raises(SystemExit, match="ceilings differ"):
        paired(a, b)
