"""The volume estimator over a sequence of frames, and its measurement on a generated recording.

``python -m liquidtwin.volumes REC.mcap [--target NAME] [--camera NAME] [--stride S]
[--bins K]`` prints the estimate per mask frame and, when the generator's truth sidecar
(``REC.truth.npz`` / ``.truth.json``) lies next to the recording, the RMSE against the true
volume (true particles inside the target cavity × the truth's ml per particle).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from .expected import MIN_DEPTH_SPACINGS, SURFACE_OFFSET_SPACINGS, LevelTable, downsample_mask, expected_masks, quat_matrix
from .hmm import VolumeFilter, default_transition, log_likelihood


def estimate_series(table: LevelTable, camera, poses, masks, stride: int = 4, filt=None,
                    occluders=None, fast: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Filtered volume of ``table.model`` over frames.

    Args:
      table: the container's :class:`LevelTable` (its volumes are the filter's bins).
      camera: :class:`~liquidtwin.camera.Camera`. poses: (T, 7) container poses per frame.
      masks: (T, H, W) bool observed liquid masks. stride: downsampling factor, px.
      filt: :class:`VolumeFilter` over ``table.volumes_ml`` (default: banded transition).
      occluders: optional callable frame index → [(trimesh solid, pose (7,)), …].
      fast: tilted surface heights from the cavity sample (``LevelTable.heights(fast=True)``).
    Returns:
      (median (T,) ml, posterior (T, K) probabilities).
    """
    poses, masks = np.asarray(poses, float), np.asarray(masks, bool)
    if poses.ndim != 2 or poses.shape[1] != 7 or masks.ndim != 3 or len(masks) != len(poses):
        raise ValueError(f"poses must be (T, 7) and masks (T, H, W) with the same T, got "
                         f"{poses.shape} and {masks.shape}")
    if filt is None:
        filt = VolumeFilter(table.volumes_ml, default_transition(len(table.volumes_ml)))
    belief = filt.initial()
    med, post = [], []
    for k, (pose, mask) in enumerate(zip(poses, masks)):
        occ = () if occluders is None else occluders(k)
        e = expected_masks(table, pose, camera, stride, occluders=occ, fast=fast)
        belief = filt.update(filt.predict(belief) if k else belief,
                             log_likelihood(e.liquid, e.interior, downsample_mask(mask, stride),
                                            fractions=e.fractions))
        med.append(filt.median(belief))
        post.append(filt.probabilities(belief))
    return np.array(med), np.array(post)


def _true_ml(path: Path, model, target: int, stamps: np.ndarray) -> np.ndarray | None:
    npz, js = path.with_suffix(".truth.npz"), path.with_suffix(".truth.json")
    if not (npz.exists() and js.exists()):
        return None
    z = np.load(npz)
    truth = json.loads(js.read_text())
    ml = next(iter(truth["fill_ml"]["reports"].values()))["particle_volume_ml"]
    out = []
    for t in stamps:
        k = int(np.searchsorted(z["pose_stamps_ns"], t))
        pose = z["true_poses"][k][target]
        local = (z["particles"][k] - pose[:3]) @ quat_matrix(pose[3:])
        out.append(model.in_cavity(local).sum() * ml)
    return np.array(out)


def main(argv=None) -> None:
    from ..camera import Camera
    from ..recordings import read_recording
    from ..scenes.spec import scene_objects, simulation_settings

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recording", type=Path)
    ap.add_argument("--target", default="target")
    ap.add_argument("--camera", default=None)
    ap.add_argument("--stride", type=int, default=4)
    ap.add_argument("--bins", type=int, default=61)
    ap.add_argument("--max-ml", type=float, default=None,
                    help="top bin, ml (default: 1.2 × the scene's fills, at most the capacity)")
    ap.add_argument("--min-depth", type=float, default=None,
                    help="thinnest liquid layer, m (default: MIN_DEPTH_SPACINGS × the scene's particle spacing)")
    ap.add_argument("--surface-offset", type=float, default=None,
                    help="visible surface below the level holding v, m (default: SURFACE_OFFSET_SPACINGS × the spacing)")
    a = ap.parse_args(argv)
    rec = read_recording(a.recording, images=False)
    items = scene_objects(rec.spec, base_dir=a.recording.parent)
    names = [n for n, _, _ in items]
    ti = names.index(a.target)
    model = items[ti][1]
    cam_name = a.camera or next(iter(rec.masks))
    info = rec.cameras[cam_name]
    camera = Camera.from_calibration(info.K, info.D, info.width, info.height, info.pose)
    stamps, masks = rec.masks[cam_name]
    poses = np.stack([rec.poses_at(int(t)) for t in stamps])          # (M, n, 7)
    fills = sum(f.volume_ml for f in rec.spec.fills)
    top = min(model.capacity_ml, 1.2 * fills if fills > 0 else model.capacity_ml) if a.max_ml is None else a.max_ml
    spacing = simulation_settings(rec.spec)["spacing"]
    depth = MIN_DEPTH_SPACINGS * spacing if a.min_depth is None else a.min_depth
    offset = SURFACE_OFFSET_SPACINGS * spacing if a.surface_offset is None else a.surface_offset
    table = LevelTable.create(model, np.linspace(0.0, top, a.bins), min_depth=depth, surface_offset=offset)
    occ = [k for k, (_, o, _) in enumerate(items) if k != ti and o.cavity is not None]
    med, _ = estimate_series(table, camera, poses[:, ti], masks, a.stride,
                             occluders=lambda f: [(items[k][1].mesh, poses[f, k]) for k in occ])
    truth = _true_ml(a.recording, model, ti, stamps)
    for i, t in enumerate(stamps):
        extra = "" if truth is None else f"  true {truth[i]:7.2f} ml"
        print(f"t {(t - stamps[0]) * 1e-9:6.3f} s  estimate {med[i]:7.2f} ml{extra}")
    if truth is not None:
        print(f"RMSE {np.sqrt(np.mean((med - truth) ** 2)):.2f} ml over {len(med)} frames "
              f"(bins {table.volumes_ml[1]:.2f} ml apart, stride {a.stride} px)")


if __name__ == "__main__":
    main()
