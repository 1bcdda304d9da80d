"""How much each hidden effect changes a generated recording's liquid masks.

Generates one recording without an effect and one per effect (same scene and seed, perfect
sensors, so the effect is the only difference), and prints per effect the mean over frames
of 1 − IOU between its masks and the plain ones, the liquid pixels in each, and how far the
stated camera pose moved. Splashing is chaotic, so 1 − IOU says the observations changed,
not how big the effect is.

    .venv/bin/python bench/effect_visibility.py [--scene pour_dump] [--seed 0] [--full]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from liquidtwin.generate import EFFECTS, generate
from liquidtwin.recordings import read_recording

#: One value per effect inside its realistic range (the generator test uses the same idea).
VALUES = {"drag": 2.5, "wind": 1.2, "viscosity": 15.0, "cohesion": 0.35, "wall_adhesion": 30.0, "leak": 0.006,
          "blockage": 0.7, "fill_error": 0.25, "time_offset": 0.1, "camera_offset": 1.5}


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default="pour_dump")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--full", action="store_true", help="the full scene instead of the quick variant")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        base_path = Path(tmp) / "none.mcap"
        generate(args.scene, base_path, seed=args.seed, quick=not args.full, noise=False)
        base = read_recording(base_path)
        _, m0 = next(iter(base.masks.values()))
        for name in EFFECTS:
            t0 = time.perf_counter()
            path = Path(tmp) / f"{name}.mcap"
            generate(args.scene, path, effects=[(name, VALUES[name])], seed=args.seed, quick=not args.full,
                     noise=False)
            rec = read_recording(path)
            _, m1 = next(iter(rec.masks.values()))
            inter, union = (m0 & m1).sum((1, 2)), (m0 | m1).sum((1, 2))
            iou = np.where(union > 0, inter / np.maximum(union, 1), 1.0)
            cam = next(iter(rec.cameras.values())).pose - next(iter(base.cameras.values())).pose
            rows.append({"effect": name, "value": VALUES[name], "mean_1_minus_iou": round(float(1 - iou.mean()), 4),
                         "liquid_px_plain": int(m0.sum()), "liquid_px_effect": int(m1.sum()),
                         "camera_pose_change": round(float(np.abs(cam).max()), 5),
                         "seconds": round(time.perf_counter() - t0, 1)})
            print(json.dumps(rows[-1]), flush=True)
    return rows


if __name__ == "__main__":
    main()
