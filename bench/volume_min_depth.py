"""Calibrate ``liquidtwin.volumes.MIN_DEPTH_SPACINGS`` (the thinnest liquid layer) on training pours.

    python bench/volume_min_depth.py [--data eval-data] [--depths 0.5 0.8 1.2 1.6 2.4]

Uses the quick training recordings of ``python -m liquidtwin.volumes.learn`` (base seed 50000,
generated into ``--data`` when missing; the evaluation uses seeds from 0). For each mask
frame it casts the target's film masks (no minimum depth) and, per candidate depth, the pool
mask once; the histogram filter (shipped transition, prior on the stated fill) then runs for
every depth from these counts, exactly as :class:`~liquidtwin.session._volumes.MaskVolumes`
scores them (pool bins: round(v / pool · |pool mask|) blocks placed on observed liquid first).
Prints the target's RMSE (ml, every mask frame) per depth vs the truth sidecar (training data).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from liquidtwin.camera import Camera
from liquidtwin.evaluate.benchmark import cases, ensure
from liquidtwin.recordings import read_recording
from liquidtwin.scenes.spec import scene_objects, simulation_settings
from liquidtwin.volumes import (P_LIQUID_IF_DRY, P_LIQUID_IF_LIQUID, LevelTable, VolumeFilter,
                                container_hits, downsample_mask, expected_masks, pixel_rays,
                                scaled_transition)
from liquidtwin.volumes.learn import true_fractions

LOGS = (np.log(P_LIQUID_IF_LIQUID), np.log1p(-P_LIQUID_IF_LIQUID), np.log(P_LIQUID_IF_DRY),
        np.log1p(-P_LIQUID_IF_DRY))


def frame_counts(path: Path, depths) -> dict:
    """Per mask frame: film-mask hits/expected per bin, observed/interior blocks, and per depth
    (pool ml, pool-mask blocks, observed blocks in it); plus bins, transition, truth."""
    import json
    rec = read_recording(path, images=False)
    items = scene_objects(rec.spec, base_dir=path.parent)
    names = [n for n, _, _ in items]
    ti, si = names.index("target"), names.index("source")
    obj, src = items[ti][1], items[si][1].mesh
    s = simulation_settings(rec.spec)["spacing"]
    bins, T = scaled_transition(sum(f.volume_ml for f in rec.spec.fills), obj.capacity_ml)
    cam_name = next(iter(rec.masks))
    info = rec.cameras[cam_name]
    cam = Camera.from_calibration(info.K, info.D, info.width, info.height, info.pose)
    stride = max(1, round(cam.width / 80))
    rays = pixel_rays(cam, stride)
    film = LevelTable.create(obj, bins)
    pools = [LevelTable.create(obj, bins, min_depth=d * s) for d in depths]
    stamps, masks = rec.masks[cam_name]
    hits, frames = None, []
    for st, m in zip(stamps, masks):
        poses = rec.poses_at(int(st))
        hits = hits or container_hits(obj, poses[ti], rays)
        occ = [(src, poses[si])]
        e = expected_masks(film, poses[ti], cam, stride, occluders=occ, fast=True, rays=rays, hits=hits)
        obs = downsample_mask(m, stride)[e.interior]
        ei = e.liquid[:, e.interior]
        fr = {"hit": (ei & obs).sum(1), "nexp": ei.sum(1), "O": int(obs.sum()), "P": int(e.interior.sum()),
              "pool": []}
        for t in pools:
            ep = expected_masks(t, poses[ti], cam, stride, occluders=occ, fast=True, rays=rays, hits=hits)
            k = min(int(np.searchsorted(bins, t.pool_ml)), len(bins) - 1)
            pm = ep.liquid[k][ep.interior]
            fr["pool"].append((t.pool_ml, int(pm.sum()), int((pm & obs).sum())))
        frames.append(fr)
    rep = next(iter(json.loads(path.with_suffix(".truth.json").read_text())["fill_ml"]["reports"].values()))
    truth = true_fractions(path)[1] * rep["particles"] * rep["particle_volume_ml"]
    return {"bins": bins, "T": T, "frames": frames, "truth": truth}


def filtered(case: dict, di: int) -> np.ndarray:
    """(M,) posterior medians, ml, with the depth ``di`` (prior on an empty target)."""
    bins = case["bins"]
    filt = VolumeFilter(bins, case["T"])
    prior = np.full(len(bins), 0.05 / len(bins))
    prior[0] += 0.95
    b, est, missed = None, [], 0
    for fr in case["frames"]:
        pool, n_pool, m_pool = fr["pool"][di]
        under = bins < pool
        nexp, hit = fr["nexp"].astype(float), fr["hit"].astype(float)
        nexp[under] = np.rint(bins[under] / pool * n_pool)
        hit[under] = np.minimum(nexp[under], m_pool)
        missed += 1
        if nexp.max() == 0:
            est.append(filt.median(b) if b is not None else 0.0)
            continue
        ll = (hit * LOGS[0] + (nexp - hit) * LOGS[1] + (fr["O"] - hit) * LOGS[2]
              + (fr["P"] - nexp - fr["O"] + hit) * LOGS[3])
        if b is None:
            b = filt.initial(prior)
        else:
            for _ in range(missed):
                b = filt.predict(b)
        missed = 0
        b = filt.update(b, ll)
        est.append(filt.median(b))
    return np.array(est)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("eval-data"), help="recording cache (default: %(default)s)")
    ap.add_argument("--depths", type=float, nargs="+", default=[0.5, 0.8, 1.2, 1.6, 2.4])
    ap.add_argument("--seed", type=int, default=50000)
    a = ap.parse_args()
    paths = ensure(cases(quick=True, trials=1, base_seed=a.seed), a.data, progress=False)
    data = [frame_counts(p, a.depths) for p in paths]
    for di, d in enumerate(a.depths):
        err = np.concatenate([filtered(c, di) - c["truth"][:len(c["frames"])] for c in data])
        print(f"min depth {d:4.2f} spacings: target RMSE {np.sqrt(np.mean(err ** 2)):6.2f} ml "
              f"over {len(err)} masks of {len(data)} training pours")


if __name__ == "__main__":
    main()
