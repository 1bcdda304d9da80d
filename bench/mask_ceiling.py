"""How well can a model mask match the observed masks at best? The TRUE particles drawn as the
model mask, scored against the recording's own (noisy) generated masks.

    OMP_NUM_THREADS=1 .venv/bin/python bench/mask_ceiling.py [--no-full] [--no-history]
    OMP_NUM_THREADS=1 .venv/bin/python bench/mask_ceiling.py --data eval-data   # every recording there

Generates (into a temporary directory, fixed seeds) one quick (320×240) and one full
(640×480) ``pour_hold`` recording, then draws the true particles (truth sidecar; scoring
only) (a) as 5 px discs (SPEC §2) and (b) as projected spheres of the model's particle
radius (what the session engine draws), occluded by the objects at their true poses, and
prints the mean IOU over frames whose observed mask has ≥ 50 px, and how many pixels each
drawing covers per observed liquid pixel over those frames. This is the ceiling of
every tracker's IOU in ``liquidtwin evaluate tracking`` and the numbers that
``session/engine.py`` cites. Appends one record per recording to bench/history.jsonl.

``--data DIR`` measures instead every recording in DIR that has a truth sidecar (e.g. the
benchmark recordings ``liquidtwin evaluate tracking --data DIR`` generated) and prints the
mean over them.

``--radius-scales S …`` also draws the spheres at S × their radius (px, after the engine's
rounding to half pixels), as the fill bank's ``radius_scale`` does, and prints for each the
pixels drawn per observed pixel pooled over every frame of every recording. It says what a
scale does to the drawing of the *true* particles; the fill bank's default
(``inference.likelihood.FILL_RADIUS_SCALE``) was not chosen by it (that module's doc says how).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch

from liquidtwin.evaluate import engine_for
from liquidtwin.evaluate.tracking import ceiling_series
from liquidtwin.generate import generate
from liquidtwin.recordings import read_recording

HISTORY = Path(__file__).parent / "history.jsonl"
SCENE, SOURCE, FILL, SEED = "pour_hold", "cup", 0.6, 5


def _commit() -> str:
    out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                         cwd=Path(__file__).parent)
    return out.stdout.strip() or "unknown"


def measure(quick: bool, tmp: Path, min_px: int = 50) -> dict:
    path = tmp / f"{SCENE}-{'quick' if quick else 'full'}.mcap"
    start = time.perf_counter()
    generate(SCENE, path, seed=SEED, quick=quick, choices={"source": SOURCE, "fraction": FILL})
    gen_s = time.perf_counter() - start
    return dict(scene=SCENE, source=SOURCE, fill=FILL, seed=SEED, quick=quick, generate_s=round(gen_s, 1),
                **measure_recording(path, min_px))


def measure_recording(path: Path, min_px: int = 50, scales=()) -> dict | None:
    """The ceilings of one recording with a truth sidecar (``path.with_suffix('.truth.npz')``);
    ``scales``: also the spheres drawn at these radius scales (labels ``spheres_xS``). None
    when its source is empty (no liquid to draw)."""
    rec = read_recording(path, images=False)
    if not len(rec.spec.fills):
        return None
    eng = engine_for(rec, "open_loop")
    cam = next(iter(rec.masks))
    out = {}
    draws = [("discs_5px", 5.0, 1.0), ("spheres", None, 1.0)] + [(f"spheres_x{s:g}", None, s) for s in scales]
    for label, disc, scale in draws:
        s = ceiling_series(rec, path, eng, cam, disc_px=disc, radius_scale=scale)
        keep = [k for k, n in enumerate(s["observed_px"]) if n >= min_px]
        out[label] = round(float(np.mean([s["iou"][k] for k in keep])), 4) if keep else None
        # > 1: the drawing covers more pixels than the camera saw liquid on
        out[f"{label}_drawn_over_observed_px"] = round(sum(s["model_px"][k] for k in keep)
                                                        / max(sum(s["observed_px"][k] for k in keep), 1), 3)
        out[f"{label}_px"] = [sum(s["model_px"][k] for k in keep), sum(s["observed_px"][k] for k in keep)]
        out["frames"] = len(keep)
    c = rec.cameras[cam]
    return dict(what="mask_ceiling", recording=Path(path).name, width=int(c.width), height=int(c.height),
                particles=eng.n_particles, mean_iou=out, min_px=min_px, commit=_commit(),
                date=datetime.now(timezone.utc).isoformat(timespec="seconds"))


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--no-full", action="store_true", help="skip the full-size recording (~1.5 min to generate)")
    p.add_argument("--no-history", action="store_true", help="do not append to bench/history.jsonl")
    p.add_argument("--data", type=Path, default=None, metavar="DIR",
                   help="measure every recording in DIR that has a truth sidecar instead of generating two")
    p.add_argument("--radius-scales", type=float, nargs="+", default=[], metavar="S",
                   help="with --data: also draw the spheres at S x their radius and print the pooled pixels "
                        "drawn per observed pixel for each S")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    records = []
    if args.data is not None:
        paths = sorted(q for q in args.data.glob("*.mcap") if q.with_suffix(".truth.npz").exists())
        if not paths:
            raise SystemExit(f"no recordings with a truth sidecar (NAME.truth.npz) in {args.data}")
        for q in paths:
            r = measure_recording(q, scales=args.radius_scales)
            if r is None:
                print(f"{q.name}: an empty source (no liquid to draw), skipped", flush=True)
                continue
            if r["mean_iou"]["frames"] == 0:
                print(f"{q.name}: no frame with >= {r['min_px']} observed liquid px, skipped", flush=True)
                continue
            print(json.dumps(r), flush=True)
            records.append(r)
        for key in ("discs_5px", "spheres", "discs_5px_drawn_over_observed_px", "spheres_drawn_over_observed_px"):
            print(f"mean over {len(records)} recordings, {key}: "
                  f"{np.mean([r['mean_iou'][key] for r in records]):.3f}", flush=True)
        for label in ["spheres"] + [f"spheres_x{s:g}" for s in args.radius_scales]:
            drawn, seen = (sum(r["mean_iou"][f"{label}_px"][i] for r in records) for i in (0, 1))
            print(f"pooled over {len(records)} recordings, {label}: {drawn / max(seen, 1):.3f} px drawn per observed "
                  f"px, mean IOU {np.mean([r['mean_iou'][label] for r in records]):.3f}", flush=True)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            for quick in (True,) if args.no_full else (True, False):
                r = measure(quick, Path(tmp))
                print(json.dumps(r), flush=True)
                records.append(r)
    if not args.no_history:
        with HISTORY.open("a") as f:
            for r in records:
                f.write(json.dumps(r) + "\n")
    return records


if __name__ == "__main__":
    main()
