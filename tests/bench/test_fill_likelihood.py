"""bench/fill_likelihood.py: its settings parser, a one-pour sweep through the CLI's main
(posteriors per setting, the summary and the JSON), and bad arguments refused."""

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.fill_likelihood import main, setting  # noqa: E402


def test_settings_parse_and_bad_ones_are_refused():
    assert setting("slack:16") == ("slack", 16.0) and setting("blur:8.5") == ("blur", 8.5)
    assert setting("exact") == ("exact", 0.0)
    for bad in ("blur", "gauss:3", "blur:x", "slack:-1", "blur:nan"):
        with pytest.raises(argparse.ArgumentTypeError):
            setting(bad)


def test_one_pour_sweep_writes_every_posterior(tmp_path, capsys):
    out = tmp_path / "sweep.json"
    doc = main(["--seeds", "1", "--scenes", "pour_partial", "--fills", "0.3", "--hypotheses", "0", "0.3",
                "--settings", "exact", "blur:32", "--data", str(tmp_path / "data"), "--json", str(out)])
    assert json.loads(out.read_text()) == doc
    assert doc["pours"] == 1 and set(doc["ranked_first"]) == {"exact:0", "blur:32"}
    row = doc["rows"][0]
    assert row["truth"] == "30 %" and row["scene"] == "pour_partial"
    for k, r in row["settings"].items():
        assert r["names"] == ["empty", "30 %"] and np.isclose(sum(r["probability"]), 1.0)
        assert doc["ranked_first"][k] == int(r["best"] == "30 %")
    # Exact pixels and the blur score the same pour differently.
    assert row["settings"]["exact:0"]["probability"] != row["settings"]["blur:32"]["probability"]
    assert "truth ranked first" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--fills", "0.6", "--data", str(tmp_path / "data")])      # 60 % is not a hypothesis
