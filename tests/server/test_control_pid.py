"""PD pour-to-volume controller on an analytic plant: flow is a known function of the tilt."""

import math

import numpy as np
import pytest
from liquidtwin.control import PourPID, thesis_gains

RATE_HZ = 30.0


def _pour(pid: PourPID, *, source_ml=100.0, onset=math.radians(55.0), k=150.0, quantum=0.0, seconds=20.0):
    """Simulate a pour: the robot follows the commanded tilt exactly; liquid leaves the source
    at q = k·(θ − onset) ml/s above the onset angle (k in ml/s per rad) while any is left;
    the volume sensor rounds down to ``quantum`` ml. Returns (poured ml, angles, done-time)."""
    dt = 1.0 / RATE_HZ
    poured, angle, angles, done_at = 0.0, pid.angle, [], None
    sub = 20
    for i in range(int(seconds * RATE_HZ)):
        seen = math.floor(poured / quantum) * quantum if quantum else poured
        angle_cmd, rate, done = pid.update(i * dt, seen)
        assert abs(rate) <= pid.max_rate + 1e-12
        assert 0.0 <= angle_cmd <= pid.max_angle + 1e-12
        if done and done_at is None:
            done_at = i * dt
        for _ in range(sub):       # the plant between two updates, the arm moving at the commanded rate
            angle = min(max(angle + rate * dt / sub, 0.0), pid.max_angle)
            flow = k * max(angle - onset, 0.0) if source_ml - poured > 0 else 0.0
            poured = min(poured + flow * dt / sub, source_ml)
        angles.append(angle)
    return poured, np.array(angles), done_at


@pytest.mark.parametrize("target,max_rate", [(20.0, 1.0), (40.0, 0.5), (70.0, 2.0)])
def test_reaches_the_target_within_tolerance_and_respects_limits(target, max_rate):
    pid = PourPID(target, math.radians(120.0), max_rate)
    poured, angles, done_at = _pour(pid)
    assert done_at is not None and done_at < 10.0
    # Within the controller's tolerance (2 %) plus what still flows while tilting back.
    assert target - pid.tolerance_ml <= poured <= target * 1.05, poured
    assert angles.max() <= math.radians(120.0) + 1e-9
    assert np.all(np.abs(np.diff(angles)) <= max_rate / RATE_HZ + 1e-9)
    assert angles[-1] == 0.0           # back upright at the end


def test_noisy_quantised_volume_and_angle_limit():
    # The sensor sees whole particles (0.07 ml); the limit stops the tilt below the onset
    # the first time, so nothing flows until... never: done stays False and the angle holds.
    pid = PourPID(30.0, math.radians(50.0), 1.0)
    poured, angles, done_at = _pour(pid, quantum=0.07)
    assert done_at is None and poured == 0.0
    assert math.isclose(angles.max(), math.radians(50.0)) and math.isclose(angles[-1], math.radians(50.0))
    pid = PourPID(30.0, math.radians(120.0), 1.0)
    poured, _, done_at = _pour(pid, quantum=0.07)
    assert done_at is not None and 30.0 - pid.tolerance_ml <= poured <= 31.5


def test_thesis_gains_pour_slowly_but_correctly():
    # Thesis gains (P = 0.01π/180 rad/s/ml, D = 0.2π/180) on a 200 ml pour, starting at 75°.
    pid = PourPID(200.0, math.radians(120.0), 0.5, angle=math.radians(75.0), **thesis_gains())
    poured, angles, done_at = _pour(pid, source_ml=400.0, onset=math.radians(70.0), k=400.0, seconds=150.0)
    assert done_at is not None and 200.0 - pid.tolerance_ml <= poured <= 210.0


def test_state_dict_round_trip_continues_identically():
    a = PourPID(25.0, 2.0, 1.0)
    for i in range(10):
        a.update(i / 30, 0.5 * i)
    b = PourPID.from_state_dict(a.state_dict())
    for i in range(10, 20):
        assert a.update(i / 30, 0.4 * i) == b.update(i / 30, 0.4 * i)


@pytest.mark.parametrize("kw", [dict(target_ml=0.0), dict(target_ml=-5.0), dict(max_angle=0.0),
                                dict(max_angle=4.0), dict(max_rate=float("nan")), dict(max_rate=0.0)])
def test_impossible_settings_are_errors(kw):
    args = dict(target_ml=10.0, max_angle=1.0, max_rate=1.0) | kw
    with pytest.raises(ValueError):
        PourPID(**args)
    with pytest.raises(ValueError):
        PourPID(10.0, 1.0, 1.0).update(float("nan"), 0.0)
