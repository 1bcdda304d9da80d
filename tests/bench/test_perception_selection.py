"""bench/perception_selection.py: the chosen-vs-last table read from an `evaluate perception
--select-every` result, on a hand-made result whose answers are known."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.perception_selection import rows, spearman  # noqa: E402


def _doc():
    pts = [{"step": 10, "select_auc": 0.1, "watch_auc": 0.30}, {"step": 20, "select_auc": 0.3, "watch_auc": 0.20},
           {"step": 25, "select_auc": 0.2, "watch_auc": 0.10}]
    net = {"kind": "fcn", "input_type": "grey", "fusion": "early", "selected_step": 20, "checkpoints": pts,
           "test": {"0": 0.20}, "train": {"0": 0.5}}
    return {"baseline": {"test": {"0": 0.04}}, "results": [net, {**net, "kind": "lstm_fcn", "checkpoints": None}]}


def test_rows_read_the_chosen_last_and_oracle_checkpoints():
    (r,) = rows(_doc(), {"results": [{"kind": "fcn", "input_type": "grey", "fusion": "early", "test": {"0": 0.05}}]})
    assert (r["chosen_step"], r["test_at_chosen"], r["calib_at_chosen"]) == (20, 0.20, 0.3)
    assert (r["test_last"], r["last_step"], r["test_oracle"], r["oracle_step"]) == (0.10, 25, 0.30, 10)
    assert r["compare"] == 0.05
    assert r["spearman"] == pytest.approx(-0.5)
    assert spearman([1, 2, 3], [3, 2, 1]) == pytest.approx(-1.0)


def test_script_prints_the_table_and_refuses_results_without_checkpoints(tmp_path):
    f = tmp_path / "perception.json"
    f.write_text(json.dumps(_doc()))
    out = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_selection.py"), str(f)],
                         capture_output=True, text=True, check=True).stdout
    assert "fcn/grey/early" in out and "chosen − last: mean +10.0 points, better on 1/1" in out
    doc = _doc()
    doc["results"] = doc["results"][1:]
    f.write_text(json.dumps(doc))
    bad = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_selection.py"), str(f)],
                         capture_output=True, text=True)
    assert bad.returncode != 0 and "--select-every" in bad.stderr
