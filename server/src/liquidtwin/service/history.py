"""A session's inputs so far, read back from its MCAP log as a :class:`Recording`.

Hidden-state inference (``infer_fill``, ``infer_blockage``) replays what the robot sent: the
same analysis ``liquidtwin evaluate`` runs on a recording file runs on a live session. The
log holds every accepted input (docs/service.md), survives restarts and kill -9, and is
re-validated here with the session's own :class:`InputChecker` rules.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from liquidtwin_proto import Hypothesis, InferenceReply, pack_array

from ..recordings.base import CameraInfo
from ..recordings.reader import Recording
from .inputs import InputChecker, InputError
from .log import read_log


class NoFramesError(ValueError):
    """The session has no usable frames yet (no poses, or no masks)."""


def session_recording(directory, spec, object_names, cameras: dict, since_ns: int = 0) -> Recording:
    """The session's accepted inputs as a Recording.

    Args:
      directory: the session's state directory (its ``log-NNNN.mcap`` segments).
      spec: the session's SessionSpec (scene, cameras).
      object_names: the scene's objects, in order.
      cameras: name → (K (3, 3), D (5,), width, height, pose (7,)) the session knows now; a
        camera pose streamed later overrides it from its stamp on.
      since_ns: only inputs the server received at or after this time (its clock, ns: the
        session's last reset).
    Returns:
      Recording: ``pose_times_ns`` = every poses sample's stamp (objects a sample does not
      name keep their previous pose), ``masks`` per camera at their stamps.
    Raises:
      NoFramesError when no poses or no masks were logged.
    """
    names = list(object_names)
    checker = InputChecker(names, {}, 1 << 31)
    for c in spec.cameras:
        if c.width and c.height:
            checker.learn_size(c.name, c.height, c.width)
    pose_rows: dict[int, dict] = {}
    masks: dict[str, dict[int, np.ndarray]] = {}
    cam_poses: dict[str, dict[int, np.ndarray]] = {}
    for rec in read_log(directory):
        if not rec.topic.startswith("/in/") or rec.log_time_ns < since_ns:
            continue
        stream, stamp = rec.topic[4:], int(rec.publish_time_ns)
        try:
            item = checker.decode(stream, rec.data)
        except InputError:
            continue                        # accepted then, refused by today's rules: skip it
        if stream == "camera":
            checker.learn(item)
        elif stream == "poses":
            pose_rows.setdefault(stamp, {}).update(item.objects)
            for name, p in item.cameras.items():
                cam_poses.setdefault(name, {})[stamp] = np.asarray(p, float)
        elif stream == "mask":
            masks.setdefault(item.camera, {})[stamp] = item.mask
    if not pose_rows:
        raise NoFramesError("the session has received no object poses yet")
    if not masks:
        raise NoFramesError("the session has received no liquid masks yet; inference scores masks")
    times = np.array(sorted(pose_rows), np.int64)
    poses = np.zeros((len(times), len(names), 7))
    current = np.tile(np.array([0, 0, 0, 0, 0, 0, 1.0]), (len(names), 1))
    for i, t in enumerate(times):
        for name, p in pose_rows[int(t)].items():
            current[names.index(name)] = p
        poses[i] = current
    infos, cam_series = {}, {}
    for name, (K, D, w, h, pose) in cameras.items():
        series = cam_poses.get(name, {})
        first = series[min(series)] if series else pose
        infos[name] = CameraInfo(name, int(w), int(h), np.asarray(K, float), np.asarray(D, float), np.asarray(first, float))
        if series:
            ts = np.array(sorted(series), np.int64)
            cam_series[name] = (ts, np.stack([series[int(t)] for t in ts]))
    mask_out = {}
    for cam, by_t in masks.items():
        if cam not in infos:
            continue
        ts = np.array(sorted(by_t), np.int64)
        mask_out[cam] = (ts, np.stack([by_t[int(t)] for t in ts]))
    if not mask_out:
        raise NoFramesError("no liquid masks of a calibrated camera with a known pose")
    stamps = np.concatenate([times] + [m[0] for m in mask_out.values()])
    return Recording(Path(directory), spec.scene, names, times, poses, infos, cam_series, mask_out, {},
                     float((stamps.max() - stamps.min()) / 1e9))


def inference_reply(header, post) -> InferenceReply:
    """An :class:`InferenceReply` from an ``inference`` Posterior (names, probability,
    log_likelihood, times_s, probability_over_time (T, K), frames, wall_s, best)."""
    hyps = [Hypothesis(name=str(n), probability=float(p), log_likelihood=float(ll))
            for n, p, ll in zip(post.names, post.probability, post.log_likelihood)]
    over = np.asarray(post.probability_over_time, np.float64).reshape(len(post.times_s), len(hyps))
    return InferenceReply(header=header, session_id=header.session_id, hypotheses=hyps, best=str(post.best),
                          times_s=[float(t) for t in post.times_s], probability_over_time=pack_array(over),
                          frames=int(post.frames), wall_s=float(post.wall_s))
