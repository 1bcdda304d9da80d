"""Frame by frame: what each tracker's model draws against what the camera saw, on one recording.

    OMP_NUM_THREADS=1 .venv/bin/python bench/tracking_frames.py REC.mcap [--trackers open_loop spnets_perception]
                                                            [--every 4] [--repeat N] [--blend]

Replays REC with each tracker as ``liquidtwin evaluate tracking`` does (``evaluate.replay``)
and prints, every ``--every`` mask frame: observed liquid px, model px, overlap px and IOU, and
how many observed px the model misses before and after the SPNets+perception tracker's noise
opening (``tracking.perception.open_mask`` at its ``NOISE_PX``; equal on commits before it,
where the tool also runs: ``PYTHONPATH=<old checkout>/server/src``); then each tracker's mean
IOU (frames with ≥ 50 observed px, as the benchmark).

``--repeat N`` replays the first tracker N times in this process and prints the first pose
sample where the particles differ from the first replay (bit for bit) and by how much.
``--blend`` prints the shipped blend net's output b on uniform disparity images (0: agreement,
+1: liquid the model misses, −1: model where no liquid is seen).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch


def frames(rec, tracker: str):
    """(Replay, [(observed, model, overlap, missed, missed after the opening) px per mask frame])."""
    from liquidtwin.evaluate.replay import engine_for, model_mask, replay
    from liquidtwin.tracking.warp import image_scale
    try:
        from liquidtwin.tracking.perception import NOISE_PX, open_mask
    except ImportError:          # a commit before the opening (stop 43): run it for "before"
        NOISE_PX, open_mask = 0.0, lambda mask, width: mask
    camera = next(iter(rec.masks))
    masks = rec.masks[camera][1]
    rows = []

    def on_frame(i, eng, c):
        if c is None:
            return
        model, seen = model_mask(c.overlay), np.asarray(masks[len(rows)], bool)
        missed = torch.from_numpy(seen & ~model)
        opened = open_mask(missed, NOISE_PX * image_scale(*seen.shape))
        rows.append((int(seen.sum()), int(model.sum()), int((model & seen).sum()), int(missed.sum()), int(opened.sum())))

    return replay(rec, engine_for(rec, tracker), camera=camera, on_frame=on_frame), rows


def first_difference(rec, tracker: str, repeats: int):
    """[(replay k, first pose sample whose particles differ from replay 0, largest difference m)]."""
    from liquidtwin.evaluate.replay import engine_for, replay
    runs = []
    for _ in range(repeats):
        xs = []
        replay(rec, engine_for(rec, tracker), on_frame=lambda i, eng, c: xs.append(np.sort(eng.positions(), axis=0)))
        runs.append(xs)
    out = []
    for k, xs in enumerate(runs[1:], 1):
        diff = next(((i, float(np.abs(a - b).max()) if a.shape == b.shape else float("inf"))
                     for i, (a, b) in enumerate(zip(runs[0], xs)) if a.shape != b.shape or not np.array_equal(a, b)),
                    (None, 0.0))
        out.append((k, *diff))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("recording", type=Path)
    p.add_argument("--trackers", nargs="+", default=["open_loop", "spnets_perception"])
    p.add_argument("--every", type=int, default=4, help="print every N-th mask frame (default: %(default)s)")
    p.add_argument("--repeat", type=int, default=0, help="replay the first tracker N times and compare")
    p.add_argument("--blend", action="store_true", help="the shipped blend net's output on uniform disparity")
    a = p.parse_args()
    if a.every < 1 or a.repeat < 0:
        p.error("--every must be >= 1 and --repeat >= 0")
    from liquidtwin.recordings import read_recording
    if a.blend:
        from liquidtwin.tracking.perception import load_blend_net
        net = load_blend_net()
        with torch.no_grad():
            for v in (0.0, 1.0, -1.0):
                print(f"blend net b on a uniform disparity of {v:+g}: {float(net(torch.full((1, 1, 40, 40), v))[0, 0, 20, 20]):.3g}")
    rec = read_recording(a.recording, images=False)
    if a.repeat:
        for k, sample, size in first_difference(rec, a.trackers[0], a.repeat):
            print(f"{a.trackers[0]} replay {k}: " + ("identical to replay 0" if sample is None else
                                                     f"first differs at pose sample {sample}, by {size:.3g} m"))
        return
    results = {t: frames(rec, t) for t in a.trackers}
    t_s = next(iter(results.values()))[0].t_s
    print("t, s  " + "  ".join(f"{t[:12]:>12}: seen model both missed opened  IOU" for t in a.trackers))
    for k in range(0, len(t_s), a.every):
        cells = []
        for r, rows in results.values():
            cells.append(" ".join(f"{v:6d}" for v in rows[k][:3]) + f" {rows[k][3]:6d} {rows[k][4]:6d} {r.iou[k]:.2f}")
        print(f"{t_s[k]:5.2f}  " + "    ".join(cells))
    for t, (r, _) in results.items():
        print(f"{t}: mean IOU {r.mean_iou():.3f}")


if __name__ == "__main__":
    main()
