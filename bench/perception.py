"""Liquid detector speed at 320×240 and end-to-end tracking with detected masks.

    python bench/perception.py --out bench/results/perception.json

1. Detector frames per second on 320×240 RGB frames (flow, network at its resolution,
   probability resized back, threshold) with 1 and 2 torch threads, per network kind
   (fresh weights: speed does not depend on them) and the shipped model.
2. Tracking IOU on generated pours with containers the detector never saw in training
   (mug → pan, perfect sensors, so the recorded masks are the true ones): the warp-field
   tracker replayed once with the true masks and once with the shipped detector's masks
   made from the RGB frames; both scored against the true masks (model mask before each
   frame's correction), over frames with ≥ 50 true liquid pixels.
Appends JSON records to bench/history.jsonl (``--no-history`` to skip).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from liquidtwin.evaluate.replay import engine_for, replay
from liquidtwin.generate import generate
from liquidtwin.perception import KINDS, build_model
from liquidtwin.perception.stream import StreamDetector, detect_recording, shared_model
from liquidtwin.recordings import read_recording

MIN_PX = 50


def fps(det: StreamDetector, frames, repeat: int = 2) -> float:
    det.reset()
    det("cam", frames[0])                                  # warm-up
    t0 = time.perf_counter()
    n = 0
    for _ in range(repeat):
        for f in frames:
            det("cam", f)
            n += 1
    return n / (time.perf_counter() - t0)


def speed(frames) -> list[dict]:
    out = []
    net, meta = shared_model()
    models = [("shipped " + meta["kind"], net, meta)]
    for kind in KINDS:
        models.append((kind, build_model(kind, meta["input_type"], meta["fusion"]).eval(), meta))
    for threads in (1, 2):
        torch.set_num_threads(threads)
        for name, n, m in models:
            r = {"what": "detector_fps", "model": name, "input": m["input_type"], "threads": threads,
                 "frame": "320x240", "network_size": m["size"], "fps": fps(StreamDetector(n, m), frames)}
            print(f"{name:<20} {threads} thread(s): {r['fps']:.1f} frames/s")
            out.append(r)
    return out


def track(path: Path) -> dict:
    rec = read_recording(path)
    cam = next(iter(rec.masks))
    t_mask, truth = rec.masks[cam]
    det_masks = detect_recording(rec, cam, StreamDetector(*shared_model()))
    res = {}
    for source, masks in (("true", truth), ("detected", det_masks)):
        r = dataclasses.replace(rec, masks={cam: (t_mask, masks)})
        res[source] = replay(r, engine_for(r, "warp_field"), camera=cam, reference=truth).mean_iou(MIN_PX)
    wet = truth.sum(axis=(1, 2)) >= MIN_PX
    inter = (det_masks & truth).sum(axis=(1, 2))
    union = (det_masks | truth).sum(axis=(1, 2))
    res["detector_iou"] = float(np.mean(inter[wet] / np.maximum(union[wet], 1)))
    res["frames"] = int(wet.sum())
    return res


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pours", type=int, default=3, help="generated unseen-container pours (default: %(default)s)")
    p.add_argument("--out", type=Path, default=None, help="also write the records here (JSON)")
    p.add_argument("--no-history", action="store_true")
    a = p.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for k, kind in enumerate(("pour_partial", "pour_hold", "pour_dump")[:a.pours]):
            path = Path(tmp) / f"{kind}.mcap"
            generate(kind, path, seed=1000 + k, quick=True, rgb=True, noise=False,
                     choices={"source": "mug", "target": "pan", "fraction": 0.9})
            paths.append(path)
        frames = read_recording(paths[0]).images
        frames = next(iter(frames.values()))[1]
        records += speed(frames)
        torch.set_num_threads(1)
        for path in paths:
            r = track(path)
            rec = {"what": "tracking_with_detected_masks", "recording": path.stem, "tracker": "warp_field",
                   "iou_true_masks": r["true"], "iou_detected_masks": r["detected"],
                   "detector_iou_vs_truth": r["detector_iou"], "frames": r["frames"]}
            print(f"{path.stem}: warp-field IOU vs true masks, tracked with true masks {r['true']:.3f}, "
                  f"with detected masks {r['detected']:.3f} (detector mask IOU {r['detector_iou']:.3f}, "
                  f"{r['frames']} frames)")
            records.append(rec)
    for r in records:
        r["commit"] = commit
    if a.out:
        a.out.write_text(json.dumps(records, indent=1) + "\n")
    if not a.no_history:
        with open(Path(__file__).resolve().parent / "history.jsonl", "a") as f:
            for r in records:
                f.write(json.dumps(r) + "\n")


if __name__ == "__main__":
    main()
