"""Calibrate the mask model's surface on training pours: ``liquidtwin.volumes.SURFACE_OFFSET_SPACINGS``
(how far below the level holding v the liquid's visible surface lies) and
``liquidtwin.volumes.hmm.SHIFT_SHARE`` (how far a sloshing surface may lie from the level
plane's place).

    OMP_NUM_THREADS=1 python bench/volume_surface_offset.py REC.mcap [REC.mcap …] [--offsets 0 0.2 0.4] [--shifts 0 0.15]

Runs the session's mask-model volume filter (``session._volumes.MaskVolumes``, exactly as a
session runs it: recorded poses and masks, the other objects occluding) over each recording
once per offset (in particle spacings) and shift (a share of the scored blocks' extent) and
prints the target's RMSE, ml, over the pour frames
(``evaluate.volume.pour_from``) and over all mask frames, against the truth sidecar (training
data: use recordings that are not the evaluation's, e.g. base seed 50000). No simulation
runs: only masks, poses and ray casts.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def rmse_per_offset(path: Path, offsets, shifts=(0.0,)) -> dict:
    """{(offset, shift): (pour RMSE, all-frames RMSE)} of the target's mask-model volume, ml."""
    from liquidtwin.camera import Camera
    from liquidtwin.evaluate.replay import engine_for
    from liquidtwin.evaluate.volume import pour_from, true_volumes
    from liquidtwin.recordings import read_recording
    from liquidtwin.session._volumes import MaskVolumes
    rec = read_recording(path, images=False)
    eng = engine_for(rec)
    scene = eng._scene                                       # read only: objects, containers, spacing
    cam_name = next(iter(rec.masks))
    info = rec.cameras[cam_name]
    cam = Camera.from_calibration(info.K, info.D, info.width, info.height, info.pose)
    stamps, masks = rec.masks[cam_name]
    truth = np.asarray(true_volumes(path, eng, stamps)["target"], float)
    poses = [rec.poses_at(int(t)) for t in stamps]
    start = pour_from(rec, stamps)
    total = scene.ml_per_particle * int(scene.state.x.shape[0])
    fills = {f.container: float(f.volume_ml) for f in rec.spec.fills}
    out = {}
    for off, shift in ((o, s) for o in offsets for s in shifts):
        mv = MaskVolumes(scene.names, scene.objects, scene.containers, scene.occluders, total,
                         float(scene.model.spacing), fills, surface_offset_spacings=off, shift=shift)
        est = []
        for f, (m, p) in enumerate(zip(masks, poses)):
            mv.update(f, cam, np.asarray(m, bool), np.asarray(p, float))
            v = mv.volumes()["target"]
            est.append(fills.get("target", 0.0) if v is None else v)
        err = np.asarray(est) - truth
        out[off, shift] = (float(np.sqrt(np.mean(err[start:] ** 2))) if start < len(err) else float("nan"),
                           float(np.sqrt(np.mean(err ** 2))))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("recordings", nargs="+", type=Path)
    p.add_argument("--offsets", nargs="+", type=float, default=None,
                   help="offsets to try, particle spacings (default: 0 0.1 0.2 0.3 0.4 0.5, or 0 with --shifts)")
    p.add_argument("--shifts", nargs="+", type=float, default=None,
                   help="sloshing moves to try, shares of the scored blocks' extent (default: 0)")
    a = p.parse_args()
    offsets = a.offsets or ([0.0] if a.shifts else [0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    shifts = a.shifts or [0.0]
    if any(o < 0 for o in offsets):
        p.error("offsets must be >= 0")
    if any(not 0 <= s <= 1 for s in shifts):
        p.error("shifts must lie in [0, 1]")
    rows = {}
    for path in a.recordings:
        rows[path.name] = rmse_per_offset(path, offsets, shifts)
        print(path.name, "  ".join(f"{o:g}/{s:g}: {r[0]:.2f}/{r[1]:.2f}" for (o, s), r in rows[path.name].items()),
              flush=True)
    print("target RMSE, ml, during pours / all frames; pooled over recordings (root mean of the squares):")
    for key in rows[a.recordings[0].name]:
        pour = np.sqrt(np.nanmean([r[key][0] ** 2 for r in rows.values()]))
        every = np.sqrt(np.mean([r[key][1] ** 2 for r in rows.values()]))
        print(f"offset {key[0]:4.2f} spacings, shift {key[1]:4.2f}: {pour:7.2f} / {every:7.2f}")


if __name__ == "__main__":
    main()
