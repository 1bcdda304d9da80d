"""The session's causal pose filter (SessionSpec.pose_filter): checked against a textbook
matrix Kalman filter, on rotations about a fixed axis against the same filter on the angle,
on what it does to a tracker's jitter, and inside a session (filtered walls, checkpoints,
bad numbers)."""

import io
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb
from liquidtwin.recordings import read_recording
from liquidtwin.scenes.motions import quat_axis_angle
from liquidtwin.session import EngineError, SessionEngine
from liquidtwin.session._pose_filter import PoseFilter, PoseFilterSettings, quat_log
from liquidtwin.sensors.poses import _quat_mul

GOLDEN = Path(__file__).parent / "data" / "golden_pour_dump.mcap"


def textbook_kalman(times, z, noise, accel, rate_std):
    """Independent reference: the full 6-state (value, rate per axis) filter in matrix form,
    x = [p, v], F = [[I, dt I], [0, I]], Q = σa² G Gᵀ ⊗ I, H = [I 0], R = σn² I."""
    eye = np.eye(3)
    x = np.concatenate([z[0], np.zeros(3)])
    P = np.block([[noise ** 2 * eye, 0 * eye], [0 * eye, rate_std ** 2 * eye]])
    H = np.hstack([eye, 0 * eye])
    out = [z[0].copy()]
    for k in range(1, len(times)):
        dt = times[k] - times[k - 1]
        F = np.block([[eye, dt * eye], [0 * eye, eye]])
        G = np.concatenate([0.5 * dt * dt * eye, dt * eye])
        x = F @ x
        P = F @ P @ F.T + accel ** 2 * G @ G.T
        S = H @ P @ H.T + noise ** 2 * eye
        K = np.linalg.solve(S, H @ P).T
        x = x + K @ (z[k] - H @ x)
        P = (np.eye(6) - K @ H) @ P
        out.append(x[:3].copy())
    return np.array(out)


def _times(rng, n=120):
    return np.cumsum(rng.uniform(1 / 90, 1 / 20, n))          # irregular frames, 20-90 Hz


def test_translation_matches_the_textbook_filter():
    rng = np.random.default_rng(0)
    t = _times(rng)
    truth = np.stack([0.1 * np.sin(2 * t), 0.05 * t, 0.02 * t * t], 1)
    z = truth + rng.normal(0, 1e-3, truth.shape)
    f = PoseFilter(PoseFilterSettings(1e-3, 0.01, 0.5, 20.0), 1)       # the motion's acceleration is ≤ 0.4 m/s²
    got = np.array([f.update(tk, 0, np.concatenate([zk, [0, 0, 0, 1]]))[:3] for tk, zk in zip(t, z)])
    ref = textbook_kalman(t, z, 1e-3, 0.5, 1.0)
    assert np.abs(got - ref).max() < 1e-12
    assert np.sqrt(((got - truth) ** 2).mean()) < 0.8 * np.sqrt(((z - truth) ** 2).mean())


def test_rotation_about_a_fixed_axis_is_the_same_filter_on_the_angle():
    rng = np.random.default_rng(1)
    t = _times(rng)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = 1.2 * np.sin(1.5 * t) + rng.normal(0, 0.01, len(t))           # measured, noisy, up to ±70°
    f = PoseFilter(PoseFilterSettings(1e-3, 0.01, 3.0, 20.0), 1)
    got = []
    for tk, a in zip(t, angle):
        q = f.update(tk, 0, np.concatenate([[0.1, 0.2, 0.3], quat_axis_angle(axis, a)]))[3:]
        w = quat_log(q)
        got.append(float(w @ axis))
        assert np.linalg.norm(w - (w @ axis) * axis) < 1e-9            # stays on the axis
    ref = textbook_kalman(t, np.stack([angle, 0 * angle, 0 * angle], 1), 0.01, 20.0, 3.0)[:, 0]
    assert np.abs(np.array(got) - ref).max() < 1e-9


def test_jitter_no_longer_reads_as_wall_speed_and_a_steady_turn_has_no_lag():
    """A cup turning at 1.5 rad/s and sliding at 0.2 m/s, poses at 30 Hz with 0.5 mm and 0.3°
    of white noise (the robot world's tracker): speeds differenced from the filtered poses
    are at least twice as close to the truth than from the raw ones, and once converged the
    filtered angle has no mean lag."""
    rng = np.random.default_rng(2)
    t = np.arange(150) / 30.0
    axis = np.array([1.0, 0.0, 0.0])
    ang = 1.5 * t
    pos = np.stack([0.2 * t, 0 * t, 0 * t], 1)
    noise_p, noise_r = 0.5e-3, math.radians(0.3)
    zp = pos + rng.normal(0, noise_p, pos.shape)
    zq = np.stack([_quat_mul(quat_axis_angle(rng.normal(size=3), rng.normal(0, noise_r) * math.sqrt(3)),
                             quat_axis_angle(axis, a)) for a in ang])
    f = PoseFilter(PoseFilterSettings(noise_p, noise_r, 0.2, 2.0), 1)   # a steady motion: low process noise
    out = np.array([f.update(tk, 0, np.concatenate([p, q])) for tk, p, q in zip(t, zp, zq)])

    def speeds(p, q):
        lin = np.linalg.norm(np.diff(p, axis=0), axis=1) * 30
        rot = np.array([np.linalg.norm(quat_log(_quat_mul(q[k + 1], q[k] * [-1, -1, -1, 1])))
                        for k in range(len(q) - 1)]) * 30
        return lin[30:], rot[30:]                             # after a second to converge

    raw_lin, raw_rot = speeds(zp, zq)
    f_lin, f_rot = speeds(out[:, :3], out[:, 3:])
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))
    assert rms(f_lin - 0.2) < rms(raw_lin - 0.2) / 2, (rms(f_lin - 0.2), rms(raw_lin - 0.2))
    assert rms(f_rot - 1.5) < rms(raw_rot - 1.5) / 2, (rms(f_rot - 1.5), rms(raw_rot - 1.5))
    lag = np.array([quat_log(_quat_mul(q, quat_axis_angle(axis, -a))) @ axis for q, a in zip(out[30:, 3:], ang[30:])])
    assert abs(lag.mean()) < noise_r / 2, lag.mean()


def test_settings_from_the_wire():
    assert PoseFilterSettings.from_spec(pb.PoseFilter()) is None
    s = PoseFilterSettings.from_spec(pb.PoseFilter(rotation_noise_rad=0.01))
    assert (s.position_noise_m, s.rotation_noise_rad, s.acceleration_m_s2) == (0.0, 0.01, 2.0)
    for bad in (dict(position_noise_m=-1e-3), dict(rotation_noise_rad=float("nan")),
                dict(position_noise_m=1e-3, acceleration_m_s2=float("inf"))):
        with pytest.raises(EngineError) as err:
            PoseFilterSettings.from_spec(pb.PoseFilter(**bad))
        assert err.value.code == pb.Error.BAD_REQUEST and "pose_filter" in str(err.value)


@pytest.fixture(scope="module")
def rec():
    return read_recording(GOLDEN, images=False)


def _engine(rec, **kw):
    return SessionEngine.create(pb.SessionSpec(scene=rec.spec, tracking=pb.OPEN_LOOP, **kw))


def _noisy(rec, seed=0):
    rng = np.random.default_rng(seed)
    p = np.asarray(rec.poses, float).copy()
    p[..., :3] += rng.normal(0, 1e-3, p[..., :3].shape)
    return p


def test_a_session_moves_its_walls_along_the_filtered_poses_and_checkpoints_the_filter(rec):
    spec_filter = pb.PoseFilter(position_noise_m=1e-3, rotation_noise_rad=1e-3)
    poses = _noisy(rec)
    t = (rec.pose_times_ns - rec.pose_times_ns[0]) * 1e-9
    a, plain = _engine(rec, pose_filter=spec_filter), _engine(rec)
    ref = PoseFilter(PoseFilterSettings.from_spec(spec_filter), len(rec.object_names))
    for i in range(12):
        frame = dict(zip(rec.object_names, poses[i]))
        a.advance(t[i], frame)
        plain.advance(t[i], frame)
        want = np.stack([ref.update(t[i], j, poses[i, j]) for j in range(len(rec.object_names))])
        assert np.allclose(a._frame_poses, want, atol=1e-12) and np.allclose(plain._frame_poses, poses[i])
    assert not np.allclose(a._frame_poses, poses[11])
    # a checkpoint holds the filter: a restored engine continues bit for bit
    buf = io.BytesIO()
    torch.save(a.state_dict(), buf)
    buf.seek(0)
    b = _engine(rec, pose_filter=spec_filter)
    b.load_state_dict(torch.load(buf, weights_only=True))
    for i in range(12, 20):
        frame = dict(zip(rec.object_names, poses[i]))
        a.advance(t[i], frame)
        b.advance(t[i], frame)
    assert np.array_equal(a._frame_poses, b._frame_poses) and np.array_equal(a.positions(), b.positions())
    # a frame with a bad pose changes nothing, the filter included
    before = a.state_dict()["pose_filter"]
    with pytest.raises(EngineError):
        a.advance(t[20], {rec.object_names[0]: poses[20, 0], rec.object_names[1]: [np.nan] * 7})
    after = a.state_dict()["pose_filter"]
    assert all(torch.equal(before[k], after[k]) for k in before)
    # reset forgets the filter's state
    a.reset()
    assert torch.isnan(a.state_dict()["pose_filter"]["t"]).all()


def test_bad_filter_settings_are_refused_before_the_scene_is_built(rec):
    with pytest.raises(EngineError) as err:
        _engine(rec, pose_filter=pb.PoseFilter(position_noise_m=-1.0))
    assert err.value.code == pb.Error.BAD_REQUEST


def test_evaluate_tracking_pose_filter_setting(rec):
    """`evaluate tracking --pose-filter`: 'auto' reads the noise off the recording's own poses
    (the generator's tracker: 0.5 mm and 0.3° white per axis), or takes given numbers."""
    import argparse
    from liquidtwin.evaluate.tracking import pose_filter_arg, pose_filter_for
    auto = pose_filter_for(rec, "auto")
    assert 0.35e-3 < auto.position_noise_m < 0.65e-3, auto
    assert math.radians(0.2) < auto.rotation_noise_rad < math.radians(0.4), auto
    given = pose_filter_for(rec, pose_filter_arg("0.001,0.01,3,30"))
    assert (given.position_noise_m, given.angular_acceleration_rad_s2) == (0.001, 30.0)
    assert pose_filter_for(rec, None) is None
    for bad in ("1", "a,b", "0.001,-1", "0.001,0.01,3", "nan,0"):
        with pytest.raises(argparse.ArgumentTypeError):
            pose_filter_arg(bad)
