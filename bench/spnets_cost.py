"""Mean IOU and wall time per frame of SPNets + perception against other trackers, on recordings.

    OMP_NUM_THREADS=1 .venv/bin/python bench/spnets_cost.py REC.mcap [REC.mcap ...] \
        [--modes open_loop warp_field spnets_perception] [--frames N]

Each recording is replayed through one session per mode (:func:`liquidtwin.evaluate.replay.replay`,
as ``liquidtwin evaluate tracking`` does); prints one JSON line per (recording, mode): mean IOU over
mask frames with ≥ 50 observed px, ms per pose sample (advance + correct, median and mean) and the
particle count. Recordings: e.g. the quick benchmark's, made by
``liquidtwin evaluate tracking --quick --trials 1 --cases 2 --data DIR``. One thread.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from liquidtwin.evaluate.replay import MODES, engine_for, replay
from liquidtwin.recordings import read_recording


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recordings", nargs="+", type=Path)
    p.add_argument("--modes", nargs="+", default=["open_loop", "warp_field", "spnets_perception"], choices=list(MODES))
    p.add_argument("--frames", type=int, default=None, help="only the first N pose samples")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    out = []
    for path in a.recordings:
        rec = read_recording(path, images=False)
        for mode in a.modes:
            eng = engine_for(rec, mode)
            ms, last = [], [time.perf_counter()]

            def tick(i, engine, corr):
                now = time.perf_counter()
                ms.append(1e3 * (now - last[0]))
                last[0] = now
            last[0] = time.perf_counter()
            r = replay(rec, eng, frames=a.frames, on_frame=tick)
            row = dict(recording=path.name, mode=mode, mean_iou=r.mean_iou(), mask_frames=len(r.iou),
                       ms_per_pose_sample_median=float(np.median(ms)), ms_per_pose_sample_mean=float(np.mean(ms)),
                       particles=eng.n_particles)
            print(json.dumps(row), flush=True)
            out.append(row)
    return out


if __name__ == "__main__":
    main()
