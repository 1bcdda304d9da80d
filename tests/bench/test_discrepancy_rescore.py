"""bench/discrepancy_rescore.py --signed-null and --sub-frame-rule: re-deciding a saved analysis from its ranking,
gains and null gains, on hand-made candidates whose answers are known."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.discrepancy_rescore import _redecide, _signed_decision  # noqa: E402


def _c(name, mean, lo, null=None):
    return {"name": name, "heldout_gain": {"mean": mean, "ci95": [lo, mean + 0.1]}, "null_gains": null}


def test_the_signed_null_bar_ignores_how_far_a_fit_loses_where_nothing_is_hidden():
    # the null fit loses 0.84: the magnitude rule's bar would be 1.28, the signed one's 0.02
    assert _signed_decision([_c("wall_adhesion", 0.95, 0.84, [-0.49, -0.84]), _c("drag", 0.5, 0.4, [0.02])]) \
        == "wall_adhesion"
    # a positive null gain still sets the bar: 1.5 × 0.4 + 0.02 = 0.62 > 0.5, the next one passes
    assert _signed_decision([_c("drag", 0.5, 0.1, [0.4, -0.2]), _c("wind", 0.3, 0.1, [0.1])]) == "wind"
    # an interval reaching zero is never checked; nothing else passes
    assert _signed_decision([_c("drag", 0.5, -0.01, None), _c("wind", 0.01, 0.005, None)]) == "none"
    # a candidate the rule would check but whose null was not computed in the run
    assert _signed_decision([_c("drag", 0.5, 0.1, None)]) == "?"


def test_the_sub_frame_rule_sets_a_short_time_offset_aside():
    stated, frame = {"lambda_v": 60.0, "lambda_c": 0.1}, 1 / 30
    short = dict(_c("time_offset", 0.158, 0.001, [0.005, 0.004]), value=-0.018)
    # the rule before declares it; the rule sets it aside and the next one, beating its null, is named
    nxt = dict(_c("wind", 0.3, 0.1, [0.0, 0.01]), value=1.0)
    assert _redecide([short, nxt], False, "spread", stated) == "time_offset"
    assert _redecide([short, nxt], False, "spread", stated, frame) == "wind"
    # the next one's null was not computed in the run: left open
    assert _redecide([short, dict(nxt, null_gains=None)], False, "spread", stated, frame) == "?"
    # an offset of two frames is declared as before; the saved rows are not changed
    long = dict(short, value=-0.07)
    assert _redecide([long, nxt], False, "spread", stated, frame) == "time_offset"
    assert "sub_frame" not in short and "declared" not in short
