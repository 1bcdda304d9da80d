"""A session's log read back as a Recording (what infer_fill / infer_blockage analyse)."""

from __future__ import annotations

import numpy as np
import pytest
from liquidtwin_client.messages import encode_camera, encode_mask, encode_poses
from liquidtwin_proto import CameraSetup, SceneSpec, SessionSpec

from liquidtwin.service.history import NoFramesError, session_recording
from liquidtwin.service.log import SessionLog

NAMES = ["cup", "bowl"]
K = np.array([[300.0, 0, 32], [0, 300.0, 24], [0, 0, 1]])
CAM_POSE = np.array([0, 0.3, 0.6, 0, 0, 0, 1.0])


def _spec():
    return SessionSpec(scene=SceneSpec(), cameras=[CameraSetup(name="cam", width=64, height=48)])


def _write(d, frames):
    log = SessionLog(d, _spec())
    log.write("/in/camera", encode_camera("cam", K, np.zeros(5), 64, 48, 1), 1, 1)
    for i, (t, poses, mask) in enumerate(frames):
        log.write("/in/poses", encode_poses(poses, t), 10 + i, t)
        if mask is not None:
            log.write("/in/mask", encode_mask("cam", mask, t), 10 + i, t)
    log.close()


def test_log_reads_back_as_recording(tmp_path):
    rng = np.random.default_rng(0)
    cup = [np.array([0.01 * i, 0, 0, 0, 0, 0, 1.0]) for i in range(4)]
    bowl = np.array([0.2, 0, 0, 0, 0, 0, 1.0])
    masks = [rng.uniform(size=(48, 64)) < 0.1 for _ in range(4)]
    frames = [(1000, {"cup": cup[0], "bowl": bowl}, masks[0]),
              (2000, {"cup": cup[1]}, None),                 # bowl keeps its pose
              (3000, {"cup": cup[2]}, masks[2]),
              (4000, {"cup": cup[3]}, masks[3])]
    _write(tmp_path, frames)
    rec = session_recording(tmp_path, _spec(), NAMES, {"cam": (K, np.zeros(5), 64, 48, CAM_POSE)})
    assert rec.pose_times_ns.tolist() == [1000, 2000, 3000, 4000]
    assert np.allclose(rec.poses[:, 0], np.stack(cup))
    assert np.allclose(rec.poses[:, 1], bowl)                  # carried forward
    stamps, got = rec.masks["cam"]
    assert stamps.tolist() == [1000, 3000, 4000]
    assert all(np.array_equal(g, masks[i]) for g, i in zip(got, (0, 2, 3)))
    assert np.allclose(rec.cameras["cam"].K, K) and np.allclose(rec.cameras["cam"].pose, CAM_POSE)
    # inputs received before a reset (server clock) are left out
    later = session_recording(tmp_path, _spec(), NAMES, {"cam": (K, np.zeros(5), 64, 48, CAM_POSE)}, since_ns=12)
    assert later.pose_times_ns.tolist() == [3000, 4000]


def test_no_masks_is_a_clear_error(tmp_path):
    _write(tmp_path, [(1000, {"cup": np.array([0, 0, 0, 0, 0, 0, 1.0])}, None)])
    with pytest.raises(NoFramesError, match="no liquid masks"):
        session_recording(tmp_path, _spec(), NAMES, {"cam": (K, np.zeros(5), 64, 48, CAM_POSE)})
    with pytest.raises(NoFramesError, match="no object poses"):
        session_recording(tmp_path / "empty", _spec(), NAMES, {})
