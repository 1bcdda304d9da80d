"""bench/impact_cost.py times the same recording's steps at its stated solver count and at
the count its falls need, and leaves bench/history.jsonl alone with --no-history (speeds are
printed, not asserted: speed is a benchmark's business)."""

import json
import subprocess
import sys
from pathlib import Path

from liquidtwin.evaluate import cases, ensure

ROOT = Path(__file__).resolve().parents[2]


def test_both_counts_are_timed_on_one_recording(tmp_path):
    ensure(cases(quick=True, trials=1)[:1], tmp_path, progress=False)        # a 30 % cup over its bowl
    rec = next(tmp_path.glob("*.mcap"))
    history = ROOT / "bench" / "history.jsonl"
    before = history.read_bytes() if history.exists() else None
    p = subprocess.run([sys.executable, str(ROOT / "bench" / "impact_cost.py"), str(rec), "--frames", "4",
                        "--no-history"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    line = json.loads([s for s in p.stdout.splitlines() if s.startswith("{")][-1])
    assert (line["stated_iterations"], line["impact_iterations"]) == (4, 8)
    assert line["particles"] > 0 and line["stated_step_ms_median"] > 0 and line["impact_step_ms_median"] > 0
    assert (history.read_bytes() if history.exists() else None) == before
    bad = subprocess.run([sys.executable, str(ROOT / "bench" / "impact_cost.py"), str(rec), "--frames", "1"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "--frames" in bad.stderr
