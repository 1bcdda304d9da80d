"""bench/warp_gain.py on one short generated pour: a run per (gain, cap) setting, the share of
moves at the cap telling a saturated field (the old gain 600) from a proportional one (50),
and the CLI's table and JSON."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.warp_gain import sweep  # noqa: E402
from liquidtwin.evaluate import cases, ensure  # noqa: E402

FRAMES = 150     # 60 Hz pose samples: liquid in view from ~1.3 s


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("warpgain")
    ensure(cases(quick=True, trials=1)[:1], d, progress=False)
    return d


def test_the_old_gain_saturates_and_the_new_one_does_not(data):
    runs = sweep(data, [(600.0, 0.25), (50.0, 0.5)], frames=FRAMES, progress=lambda s: None)
    old, new = runs
    assert old["gain"] == 600.0 and new["max_move"] == 0.5 and len(old["cases"]) == 1
    assert 0.0 < old["pooled_iou"] < 1.0 and 0.0 < new["pooled_iou"] < 1.0
    assert old["at_cap"] > 0.6 and new["at_cap"] < 0.3, (old["at_cap"], new["at_cap"])


def test_cli_prints_the_paired_difference_and_writes_json(data, tmp_path):
    out = tmp_path / "sweep.json"
    p = subprocess.run([sys.executable, str(ROOT / "bench" / "warp_gain.py"), "--data", str(data), "--gains", "600,50",
                        "--max-move", "0.25,0.5", "--frames", "90", "--out", str(out)],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    assert "gain 600, cap 0.25 h: pooled IOU" in p.stdout and "better on" in p.stdout
    doc = json.loads(out.read_text())
    assert [r["gain"] for r in doc["runs"]] == [600.0, 50.0]
    pooled = subprocess.run([sys.executable, str(ROOT / "bench" / "warp_gain.py"), "--combine", str(out), str(out)],
                            capture_output=True, text=True, timeout=60)
    assert pooled.returncode == 0 and "(2 pours;" in pooled.stdout, pooled.stdout + pooled.stderr
    bad = subprocess.run([sys.executable, str(ROOT / "bench" / "warp_gain.py"), "--data", str(data), "--gains", "1,2,3",
                          "--max-move", "0.1,0.2"], capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "one cap or one per gain" in bad.stderr
    bad = subprocess.run([sys.executable, str(ROOT / "bench" / "warp_gain.py"), "--data", str(data), "--gains", "600",
                          "--agreeing", "1.5"], capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "--agreeing takes shares in [0, 1]" in bad.stderr


def test_agreeing_share_is_a_setting_of_the_sweep(data):
    runs = sweep(data, [(600.0, 0.25), (600.0, 0.25, 0.0)], frames=90, progress=lambda s: None)
    assert [r["agreeing_share"] for r in runs] == [1.0, 0.0]
    a, b = runs[0]["pooled_iou"], runs[1]["pooled_iou"]
    assert 0 < a < 1 and 0 < b < 1 and a != b                       # agreeing particles held still change the run
