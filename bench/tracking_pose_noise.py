"""How much tracking IOU the object tracker's pose noise costs: replay recordings through a
session engine with the recorded poses, the same poses smoothed offline (zero-phase, the
discrepancy analysis's smoothing: a bound on what any causal filter could do), and the true
poses from the truth sidecar (scoring/diagnostic only).

    OMP_NUM_THREADS=1 .venv/bin/python bench/tracking_pose_noise.py --data DIR [--trackers open_loop warp_field]

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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="directory of REC.mcap + REC.truth.npz")
    p.add_argument("--trackers", nargs="+", default=["open_loop"])
    p.add_argument("--min-px", type=int, default=50)
    p.add_argument("--limit", type=int, default=None, help="only the first N recordings (sorted by name)")
    p.add_argument("--out", type=Path, help="JSON file for the results")
    args = p.parse_args()
    import torch
    torch.set_num_threads(1)
    from liquidtwin.evaluate.replay import engine_for, replay
    from liquidtwin.recordings import read_recording
    from liquidtwin.recordings._interp import POSE_SMOOTHING_S, interpolate_poses, smooth_poses

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
        for tracker in args.trackers:
            for name, poses in series.items():
                r = dataclasses.replace(rec, poses=np.asarray(poses, float))
                row[f"{tracker}/{name}"] = replay(r, engine_for(r, tracker)).mean_iou(args.min_px)
        rows.append(row)
        print(path.name, "  ".join(f"{k} {v:.3f}" if v is not None else f"{k} -" for k, v in row.items() if k != "recording"),
              flush=True)
    keys = [k for k in rows[0] if k != "recording"]
    means = {k: float(np.mean([r[k] for r in rows if r[k] is not None])) for k in keys}
    print("\nmean IOU over", len(rows), "recordings:", "  ".join(f"{k} {v:.3f}" for k, v in means.items()))
    if args.out:
        args.out.write_text(json.dumps({"rows": rows, "mean": means, "min_px": args.min_px}, indent=1))


if __name__ == "__main__":
    main()
