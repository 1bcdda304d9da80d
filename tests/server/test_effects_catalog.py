"""The effect catalogue: names match the discrepancy contract, ranges are sane, parsing and
sampling behave and fail clearly."""

import numpy as np
import pytest

from liquidtwin.generate.effects import EFFECTS, Effect, parse_effect, sample_effect

CANONICAL = ["drag", "wind", "viscosity", "cohesion", "wall_adhesion", "leak", "blockage", "fill_error",
             "time_offset", "camera_offset"]


def test_catalogue_has_exactly_the_canonical_names():
    assert list(EFFECTS) == CANONICAL
    for e in EFFECTS.values():
        assert e.kind in ("physics", "geometry", "initial", "observation")
        assert e.ranges and all(lo < hi for lo, hi in e.ranges)


@pytest.mark.parametrize("name", CANONICAL)
def test_samples_fall_in_the_realistic_range_and_vary_with_the_seed(name):
    values = {sample_effect(name, np.random.default_rng(s)).value for s in range(20)}
    assert len(values) > 10
    assert all(EFFECTS[name].contains(v) for v in values)


def test_sampling_is_deterministic_and_keeps_a_given_value():
    a = sample_effect("leak", np.random.default_rng(3))
    b = sample_effect("leak", np.random.default_rng(3))
    assert a == b and set(a.extra) == {"height_fraction", "azimuth_deg"}
    assert sample_effect("drag", np.random.default_rng(0), 2.5).value == 2.5
    off = sample_effect("camera_offset", np.random.default_rng(1))
    assert np.linalg.norm(off.extra["axis"]) == pytest.approx(1.0)
    assert 0.005 <= np.linalg.norm(off.extra["shift_m"]) <= 0.015


def test_parse_effect():
    assert parse_effect("drag=2.5") == ("drag", 2.5)
    assert parse_effect("time_offset=-0.08") == ("time_offset", -0.08)
    assert parse_effect("leak") == ("leak", None)
    with pytest.raises(ValueError, match="unknown effect 'gravity'"):
        parse_effect("gravity=1")
    with pytest.raises(ValueError, match="not a number"):
        parse_effect("drag=fast")
    with pytest.raises(ValueError, match="finite"):
        parse_effect("drag=nan")
    with pytest.raises(ValueError, match="unknown effect"):
        Effect("magic", 1.0)
