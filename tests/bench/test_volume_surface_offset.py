"""bench/volume_surface_offset.py: at offset 0 and shift 0 it reproduces the mask-model RMSE of
``liquidtwin evaluate volume`` on the same recording (it runs the session's filter without the
simulation), and on a quick pour, whose target volumes all lie in the bowl's thinnest-layer
pool, neither an offset nor a shift (which moves only whole surfaces) changes anything;
negative offsets and shifts outside [0, 1] are refused."""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.volume_surface_offset import main, rmse_per_offset  # noqa: E402


@pytest.fixture(scope="module")
def quick_pour(tmp_path_factory):
    from liquidtwin.evaluate.benchmark import cases, ensure
    case = cases(quick=True, trials=1, base_seed=0)[0]                 # partial pour of a 30 % cup
    return ensure([case], tmp_path_factory.mktemp("data"), jobs=1, progress=False)[0]


def test_offset_zero_is_the_benchmarks_mask_column_and_quick_pools_ignore_the_offset(quick_pour):
    from liquidtwin.evaluate.volume import case_rmse, evaluate_case
    got = rmse_per_offset(quick_pour, [0.0, 0.5], [0.0, 0.15])
    want = case_rmse(evaluate_case(quick_pour, ["open_loop"]))["mask"]
    assert got[0.0, 0.0] == pytest.approx((want["target pour"], want["target all"]), rel=1e-9)
    assert got[0.5, 0.0] == got[0.0, 0.0] == got[0.0, 0.15] == got[0.5, 0.15]


@pytest.mark.parametrize("args", [["--offsets", "-0.1"], ["--shifts", "1.5"]])
def test_negative_offsets_and_big_shifts_are_refused(quick_pour, monkeypatch, args):
    monkeypatch.setattr(sys, "argv", ["volume_surface_offset.py", str(quick_pour)] + args)
    with pytest.raises(SystemExit):
        main()
