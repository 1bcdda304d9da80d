"""Generate a recording with a hidden effect, read it back, and compare it with the truth.

Writes two quick ``pour_hold`` recordings with the same seed — one plain, one with an effect
hidden in the world (default: the camera's stated extrinsics are 2° off) — reads each as any
consumer would (``read_recording``: scene spec, tracker
poses, calibration, liquid masks), rebuilds the objects from the recording's scene spec, and
draws liquidtwin's model mask (discs of 3 px at this half resolution, occlusion by the objects) of the *true* particles
from the sidecar as seen by the *stated* camera. The IOU with the observed masks, plain vs
hidden effect, shows what the effect costs a model that ignores it. (Only this illustration
opens the truth; analyses never do.)

    python examples/03_generate_and_read.py --effect camera_offset=2.0 --steps 30
"""

import argparse
from pathlib import Path

import numpy as np
import torch

from liquidtwin.camera import Camera, visible
from liquidtwin.camera.render import iou, model_mask
from liquidtwin.generate import generate, parse_effect
from liquidtwin.recordings import read_recording
from liquidtwin.scenes.spec import scene_objects


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--effect", default="camera_offset=2.0", help="NAME=VALUE or 'none' (default: %(default)s)")
    parser.add_argument("--steps", type=int, default=60, help="mask frames to compare (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--out", default="out/03_generated.mcap", help="recording to write (default: %(default)s)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)

    effects = [] if args.effect == "none" else [parse_effect(args.effect)]
    out = Path(args.out)
    result = {}
    for label, hidden in (("plain", []), (args.effect, effects)):
        path = out.with_name(f"{out.stem}_{'plain' if not hidden else hidden[0][0]}{out.suffix}")
        generate("pour_hold", path, effects=hidden, seed=args.seed, quick=True)
        result[label] = _score(path, args.steps)
        print(f"{label:>22}: model mask of the true particles vs observed, mean IOU "
              f"{result[label]:.3f} ({path})")
    return result


def _score(path: Path, frames: int) -> float:
    rec = read_recording(path)
    name, info = next(iter(rec.cameras.items()))
    times, masks = rec.masks[name]
    camera = Camera.from_calibration(info.K, info.D, info.width, info.height, torch.as_tensor(info.pose), name)
    objects = [(n, m.sdf()) for n, m, _ in scene_objects(rec.spec) if n != "table"]
    grids = [g for _, g in objects]
    index = [list(rec.object_names).index(n) for n, _ in objects]
    truth = np.load(path.with_suffix(".truth.npz"), allow_pickle=False)      # illustration only
    scores = []
    for t, observed in list(zip(times, masks))[:frames]:
        k = int(np.argmin(np.abs(truth["pose_stamps_ns"] - t)))
        x = torch.as_tensor(truth["particles"][k], dtype=torch.float64)
        poses = torch.as_tensor(rec.poses_at(int(t)))[index]
        seen = visible(camera, x, grids, poses, margin_px=5.0)
        uv, _ = camera.project(x)
        model = model_mask(uv, seen, info.height, info.width, radius_px=3.0)
        if observed.sum() > 50:                     # frames where the camera sees liquid
            scores.append(iou(model, torch.from_numpy(observed)))
    return float(np.mean(scores)) if scores else float("nan")


if __name__ == "__main__":
    main()
