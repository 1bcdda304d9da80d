"""How much tracking IOU the object tracker's pose noise costs: replay recordings through a
session engine with the recorded poses, the same poses smoothed offline (zero-phase, the
discrepancy analysis's smoothing: a bound on what any causal filter could do), the recorded
poses through the session's causal pose filter (``--filter``), and the true poses from the
truth sidecar (scoring/diagnostic only).

    OMP_NUM_THREADS=1 .venv/bin/python bench/tracking_pose_noise.py --data DIR [--trackers open_loop warp_field] \
        [--filter 2,20 0.5,5]

``DIR``: recordings with truth sidecars, e.g. those ``liquidtwin evaluate tracking --quick
--trials 1 --data DIR`` generates. The IOU is the tracking table's: mean over frames whose
observed mask has at least ``--min-px`` liquid pixels, model mask before the correction.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np


def pose_errors(t: np.ndarray, poses: np.ndarray, true: np.ndarray) -> dict:
    """RMS against the true poses over every object and sample: position (mm), rotation (deg),
    and the speeds a simulator differences from them (linear m/s, angular rad/s)."""
    from liquidtwin.sensors.poses import _quat_mul
    from liquidtwin.session._pose_filter import quat_inverse, quat_log

    dp = np.linalg.norm(poses[..., :3] - true[..., :3], axis=-1)
    dr = np.linalg.norm(quat_log(_quat_mul(poses[..., 3:], quat_inverse(true[..., 3:]))), axis=-1)
    dt = np.diff(t)[:, None]
    vel = lambda p: np.diff(p[..., :3], axis=0) / dt[..., None]
    ang = lambda p: quat_log(_quat_mul(p[1:, :, 3:], quat_inverse(p[:-1, :, 3:]))) / dt[..., None]
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))
    return {"position_mm": 1e3 * rms(dp), "rotation_deg": float(np.degrees(rms(dr))),
            "speed_m_s": rms(np.linalg.norm(vel(poses) - vel(true), axis=-1)),
            "angular_speed_rad_s": rms(np.linalg.norm(ang(poses) - ang(true), axis=-1))}


def filter_offline(t: np.ndarray, poses: np.ndarray, msg) -> np.ndarray:
    """What a session's pose filter makes of a (K, M, 7) series: its frame poses, causally."""
    from liquidtwin.session._pose_filter import PoseFilter, PoseFilterSettings

    f = PoseFilter(PoseFilterSettings.from_spec(msg), poses.shape[1])
    return np.stack([[f.update(tk, j, pk[j]) for j in range(poses.shape[1])] for tk, pk in zip(t, poses)])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="directory of REC.mcap + REC.truth.npz")
    p.add_argument("--trackers", nargs="+", default=["open_loop"])
    p.add_argument("--min-px", type=int, default=50)
    p.add_argument("--limit", type=int, default=None, help="only the first N recordings (sorted by name)")
    p.add_argument("--filter", nargs="*", default=[], metavar="ACC,ANGACC",
                   help="replay also through the session's pose filter with these process noises "
                        "(m/s², rad/s²; one series each)")
    p.add_argument("--filter-noise", default="0.0005,0.005236", metavar="M,RAD",
                   help="the filter's measurement noise: the generator's tracker, 0.5 mm and 0.3° "
                        "(default: %(default)s)")
    p.add_argument("--series", nargs="+", default=["recorded", "smoothed", "true"],
                   choices=("recorded", "smoothed", "true"), help="pose series besides the filtered ones")
    p.add_argument("--no-replay", action="store_true",
                   help="pose errors only, no tracking replays (seconds for any number of --filter settings)")
    p.add_argument("--out", type=Path, help="JSON file for the results")
    args = p.parse_args()
    import torch
    torch.set_num_threads(1)
    from liquidtwin.evaluate.replay import engine_for, replay
    from liquidtwin.recordings import read_recording
    from liquidtwin.recordings._interp import POSE_SMOOTHING_S, interpolate_poses, smooth_poses
    from liquidtwin_proto import liquidtwin_pb2 as pb

    pos_noise, rot_noise = (float(v) for v in args.filter_noise.split(","))
    filters = {}
    for f in args.filter:
        acc, ang = (float(v) for v in f.split(","))
        filters[f"filtered({acc:g},{ang:g})"] = pb.PoseFilter(position_noise_m=pos_noise, rotation_noise_rad=rot_noise,
                                                              acceleration_m_s2=acc, angular_acceleration_rad_s2=ang)

    paths = sorted(q for q in args.data.glob("*.mcap") if q.with_suffix(".truth.npz").exists())[: args.limit]
    if not paths:
        raise SystemExit(f"no recordings with truth sidecars in {args.data}")
    rows = []
    for path in paths:
        rec = read_recording(path, images=False)
        t = (rec.pose_times_ns - rec.pose_times_ns[0]) * 1e-9
        z = np.load(path.with_suffix(".truth.npz"), allow_pickle=False)
        tp = z["true_poses"].astype(float)
        true = np.stack([interpolate_poses(z["pose_stamps_ns"].astype(np.int64), tp[:, j], rec.pose_times_ns)
                         for j in range(tp.shape[1])], 1)
        series = {"recorded": rec.poses, "smoothed": smooth_poses(t, np.asarray(rec.poses, float), POSE_SMOOTHING_S),
                  "true": true}
        row = {"recording": path.name}
        recorded = np.asarray(rec.poses, float)
        row["pose_error"] = {name: pose_errors(t, np.asarray(series[name], float), true) for name in ("recorded", "smoothed")}
        row["pose_error"].update({name: pose_errors(t, filter_offline(t, recorded, msg), true)
                                  for name, msg in filters.items()})
        for tracker in [] if args.no_replay else args.trackers:
            for name in args.series:
                r = dataclasses.replace(rec, poses=np.asarray(series[name], float))
                row[f"{tracker}/{name}"] = replay(r, engine_for(r, tracker)).mean_iou(args.min_px)
            for name, filt in filters.items():
                row[f"{tracker}/{name}"] = replay(rec, engine_for(rec, tracker, pose_filter=filt)).mean_iou(args.min_px)
        rows.append(row)
        print(path.name, "  ".join(f"{k} {v:.3f}" if v is not None else f"{k} -" for k, v in row.items()
                                   if k not in ("recording", "pose_error")), flush=True)
        for name, e in row["pose_error"].items():
            print(f"   {name:>22}: " + "  ".join(f"{k} {v:.4f}" for k, v in e.items()), flush=True)
    keys = [k for k in rows[0] if k not in ("recording", "pose_error")]
    means = {k: float(np.mean([r[k] for r in rows if r[k] is not None])) for k in keys}
    print("\nmean IOU over", len(rows), "recordings:", "  ".join(f"{k} {v:.3f}" for k, v in means.items()))
    errors = {name: {k: float(np.mean([r["pose_error"][name][k] for r in rows])) for k in e}
              for name, e in rows[0]["pose_error"].items()}
    for name, e in errors.items():
        print(f"pose error, mean over recordings, {name:>22}: " + "  ".join(f"{k} {v:.4f}" for k, v in e.items()))
    if args.out:
        args.out.write_text(json.dumps({"rows": rows, "mean": means, "pose_error": errors, "min_px": args.min_px,
                                              "filter_noise": [pos_noise, rot_noise]}, indent=1))


if __name__ == "__main__":
    main()
