"""bench/pour_iterations.py on seed 1's robot world: SPNets' cohesion, applied in full every
solver iteration, makes the iteration count part of the liquid; ``reference_iterations``
(SimulationSettings) keeps the liquid while the count changes.

Measured (the bench, 3 s): 19.5 ml left the cup at 4 iterations, 2.35 ml at 12 with SPNets'
cohesion and 16.7 ml at 12 with the cohesion of 4; with no cohesion 23.9 and 23.3 ml."""

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.pour_iterations import main  # noqa: E402


def left(out, iterations):
    return next(r["left_ml"][-1] for r in out["rows"] if r["who"] == "twin" and r["iterations"] == iterations)


def test_more_iterations_stop_an_spnets_pour_unless_cohesion_is_per_step(tmp_path, capsys):
    args = ["--seeds", "1", "--iterations", "4", "12", "--seconds", "2.5"]
    spnets = main(args + ["--json", str(tmp_path / "spnets.json")])
    per_step = main(args + ["--cohesion", "per-step", "--reference", "4"])
    table = capsys.readouterr().out
    assert "left cup" in table and json.loads((tmp_path / "spnets.json").read_text())["rows"][0]["who"] == "world"
    assert left(spnets, 4) == left(per_step, 4) > 10.0          # the same model at the reference count
    assert left(spnets, 12) < 0.25 * left(spnets, 4)             # three times the cohesion: it barely pours
    assert abs(left(per_step, 12) - left(per_step, 4)) < 0.25 * left(per_step, 4)   # the same liquid, solved better
    world = next(r for r in spnets["rows"] if r["who"] == "world")
    assert world["iterations"] == 6 and left(spnets, 4) > world["left_ml"][-1] > 0.5 * left(spnets, 4)
