"""``liquidtwin evaluate tracking``: the thesis's Fig. 7.5 table on the generated pouring benchmark.

Every benchmark recording (:mod:`.benchmark`) is replayed through one
:class:`~liquidtwin.session.SessionEngine` per tracker (:func:`.replay.replay`); each mask frame
gives the IOU of the model mask against the observed mask *before* that frame's correction.
Table rows: cup, bottle, 30 %, 60 %, 90 %, overall; a cell is the mean IOU over the row's
frames whose observed mask has ≥ ``--min-px`` liquid pixels (50), pooled over its cases.

The "ceiling" column is scoring only: the *true* particles (the generator's truth sidecar,
which no tracker ever sees) drawn with the engine's model mask (projected spheres of the
model's particle radius, occluded by the objects at their true poses) against the same
observed masks — what mask noise and drawing alone cost, the best any tracker could score.

``--masks detected`` feeds the closed-loop trackers the masks the server's RGB detector
(:mod:`liquidtwin.perception.stream`) finds in the recordings' synthetic RGB frames, as a
session with ``mask_source = "rgb"`` would, and scores them against the *recorded* masks like
every other column (column ``TRACKER/detected``). The benchmark is then generated with RGB
frames (cases named ``…-rgb``: other recordings than the plain ones of the same seeds). Open
loop never reads a mask: it keeps its one column, scored against the recorded masks.

A tracker whose session cannot be created (EngineError INFEASIBLE, e.g. a mode not built
yet) gets "n/a" in its column. Results: ``results.json`` (every case with its seed and
parameters, every IOU series), ``table.png`` (bars of the table) and ``iou_time.png``. ``--jobs``
processes generate the missing recordings and then replay the cases (one case per process).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from ..procs import map_jobs
from .benchmark import ensure
from .cli import (CASES_HELP, IMPACT, add_common, add_model_options, case_range, model_options_note, save_results,
                  selected_cases, solver_iterations, with_model_options)
from .replay import MODES, engine_for, replay

HELP = "closed-loop tracking IOU per tracker on the pouring benchmark (thesis Fig. 7.5)"
TRACKERS = ("open_loop", "map_filter", "warp_field", "spnets_perception")
LABELS = {"open_loop": "open loop", "map_filter": "MAP", "warp_field": "warp", "spnets_perception": "SPNets+perc",
          "ceiling": "ceiling", "map_filter/detected": "MAP det", "warp_field/detected": "warp det",
          "spnets_perception/detected": "SPNets det"}
MASK_SOURCES = ("recorded", "detected")
ROWS = ("cup", "bottle", "30 %", "60 %", "90 %", "overall")


def configure(p) -> None:
    add_common(p, out="eval-tracking")
    add_model_options(p)
    p.add_argument("--trackers", nargs="+", default=list(TRACKERS), choices=list(MODES), metavar="T",
                   help=f"trackers to compare, from {', '.join(MODES)} (default: all)")
    p.add_argument("--cases", type=case_range, default=None, metavar="N|A:B", help=CASES_HELP)
    p.add_argument("--frames", type=int, default=None, metavar="N",
                   help="only the first N pose samples of each recording (default: all)")
    p.add_argument("--min-px", type=int, default=50, metavar="PX",
                   help="frames count only when the observed mask has at least this many liquid px (default: 50)")
    p.add_argument("--masks", nargs="+", default=["recorded"], choices=MASK_SOURCES, metavar="SRC",
                   help="what the closed-loop trackers correct with: 'recorded' (the recordings' masks) and/or "
                        "'detected' (the RGB detector's masks; generates the benchmark with RGB frames). Every "
                        "column is scored against the recorded masks (default: recorded)")
    p.add_argument("--detector", type=Path, default=None, metavar="MODEL.pt",
                   help="liquid detector for --masks detected (default: the shipped model)")
    p.add_argument("--pose-filter", nargs="?", const="auto", default=None, type=pose_filter_arg,
                   metavar="auto|M,RAD[,ACC,ANGACC]",
                   help="replay with the session's pose filter (SessionSpec.pose_filter): 'auto' (the "
                        "default when given without a value) sets its noise to the level estimated from each "
                        "recording's own poses; or the tracker's noise in m and rad, and optionally the "
                        "process noise in m/s² and rad/s² (default: no filter)")


def pose_filter_arg(text: str) -> str:
    """--pose-filter's value, checked: "auto" or M,RAD[,ACC,ANGACC] (numbers >= 0)."""
    from liquidtwin_proto.pose_filter import parse_pose_filter
    if text != "auto":
        try:
            parse_pose_filter(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(f"expected 'auto' or {e}") from None
    return text


def pose_filter_for(rec, setting: str | None):
    """The ``pb.PoseFilter`` of a --pose-filter setting for recording ``rec`` (None: no filter).
    "auto": the median over objects of the white noise level estimated from the recording's
    own poses (``recordings._interp.pose_noise_level``), default process noise."""
    if setting is None:
        return None
    from liquidtwin_proto import liquidtwin_pb2 as pb
    if setting == "auto":
        from ..recordings._interp import pose_noise_level
        pos, rot = np.median(pose_noise_level(np.asarray(rec.poses, float)), axis=0)
        return pb.PoseFilter(position_noise_m=float(pos), rotation_noise_rad=float(rot))
    from liquidtwin_proto.pose_filter import parse_pose_filter
    return parse_pose_filter(setting)


def columns_for(trackers, masks) -> list[str]:
    """Table columns: each tracker per mask source (``TRACKER/detected`` for detected masks;
    open loop only once, it reads no mask), then the ceiling."""
    cols = []
    for src in masks:
        cols += [t if src == "recorded" or t == "open_loop" else f"{t}/{src}" for t in trackers]
    return list(dict.fromkeys(cols)) + ["ceiling"]


def table(results: list[dict], columns: list[str], min_px: int) -> dict:
    """{row: {column: mean IOU or None}} pooled over the row's qualifying frames."""
    out = {}
    for row in ROWS:
        out[row] = {}
        for col in columns:
            vals = []
            for r in results:
                s = r["series"].get(col)
                if s is not None and row in _row_of(r["case"]):
                    vals += [i for i, n in zip(s["iou"], s["observed_px"]) if n >= min_px]
            out[row][col] = float(np.mean(vals)) if vals else None
    return out


def _row_of(case: dict) -> tuple[str, ...]:
    return (case["source"], f"{round(case['fraction'] * 100)} %", "overall")


def format_table(tab: dict, columns: list[str], min_px: int, note: str) -> str:
    w = 12
    lines = ["row".ljust(9) + "".join(LABELS.get(c, c).rjust(w) for c in columns)]
    for row in ROWS:
        cells = ["n/a" if tab[row][c] is None else f"{100 * tab[row][c]:.1f} %" for c in columns]
        lines.append(row.ljust(9) + "".join(x.rjust(w) for x in cells))
    lines.append(f"mean IOU (model mask vs observed mask, before each correction) over frames whose observed "
                 f"mask has >= {min_px} px (n/a: tracker not available, or no such frames); {note}")
    return "\n".join(lines)


def ceiling_series(rec, path: Path, engine, camera: str, frames: int | None = None, *,
                   disc_px: float | None = None, radius_scale: float = 1.0) -> dict:
    """Scoring only: IOU of the true particles, drawn as the engine draws its model, vs each
    observed mask of ``camera`` (reads the truth sidecar ``REC.truth.npz``).

    Args:
      rec: the :class:`~liquidtwin.recordings.Recording` of ``path``; engine: a SessionEngine
        built for it (its model's objects, particle radius and camera calibration are used).
      frames: only masks up to the ``frames``-th pose sample (None: all).
      disc_px: draw fixed discs of this radius, px (SPEC §2's 5 px) instead of projected spheres.
      radius_scale: the projected spheres' radii (px, as the engine rounds them) × this, as a
        hypothesis bank's ``radius_scale`` draws them.
    Returns:
      {"t_s": [...] s, "iou": [...], "observed_px": [...], "model_px": [...]} per mask frame
      (``model_px``: pixels the true particles cover when drawn this way).
    """
    import torch
    from ..camera import model_mask, sphere_coverage, sphere_radius_px, visible
    from ..camera import iou as mask_iou
    from ..session.engine import MIN_RADIUS_PX, NEAR_M, OCCLUSION_MARGIN_PX
    from ..sim import particle_radius
    truth = np.load(Path(path).with_suffix(".truth.npz"))
    scene = engine._scene                                   # read only: the model the session draws with
    objects = [scene.model.objects[k] for k in scene.occluders]
    radius = particle_radius(float(scene.model.spacing))
    cam = engine._cameras.camera(camera)
    stamps, masks = rec.masks[camera]
    limit = _last_stamp(rec, frames)
    t0 = int(rec.pose_times_ns[0])
    out = {"t_s": [], "iou": [], "observed_px": [], "model_px": []}
    pose_stamps = truth["pose_stamps_ns"]
    for s, m in zip(stamps, masks):
        if limit is not None and s > limit:
            break
        j = int(np.argmin(np.abs(pose_stamps - s)))
        x = torch.as_tensor(truth["particles"][j], dtype=torch.float64)
        poses = torch.as_tensor(truth["true_poses"][j], dtype=torch.float64)
        with torch.no_grad():
            seen = visible(cam, x, objects, poses[list(scene.occluders)], margin_px=OCCLUSION_MARGIN_PX, near=NEAR_M)
            uv, depth = cam.project(x)
            if disc_px is None:
                r = sphere_radius_px(cam.fx, depth, radius, min_px=MIN_RADIUS_PX) * radius_scale
                model = sphere_coverage(uv, r, seen, cam.height, cam.width) > 0
            else:
                model = model_mask(uv, seen, cam.height, cam.width, float(disc_px))
        obs = torch.as_tensor(np.asarray(m, bool))
        out["t_s"].append((int(s) - t0) * 1e-9)
        out["iou"].append(float(mask_iou(model.cpu(), obs)))
        out["observed_px"].append(int(obs.sum()))
        out["model_px"].append(int(model.sum()))
    return out


def evaluate_case(path: Path, trackers, *, frames: int | None = None, ceiling: bool = True,
                  iterations: int | None = None, masks=("recorded",), detector: Path | None = None,
                  pose_filter: str | None = None, max_correction: float | None = None,
                  cut_wall_pairs: bool = False) -> dict:
    """{column (:func:`columns_for`): {"t_s", "iou", "observed_px"} or None (tracker not
    available)}; ``iterations``: the model's solver iterations (None: the recording's);
    ``masks``: mask sources; ``detector``: model file for detected masks (None: shipped);
    ``pose_filter``: a --pose-filter setting for every tracker's session (:func:`pose_filter_for`);
    ``max_correction``, ``cut_wall_pairs``: the model's cap and wall cut (``cli.with_model_options``).
    With detected masks, also "detector": the detector's masks against the recorded ones."""
    import dataclasses

    from ..recordings import read_recording
    from ..session.errors import INFEASIBLE, EngineError
    rec = with_model_options(read_recording(path, images="detected" in masks), iterations, max_correction,
                             cut_wall_pairs)
    camera = next(iter(rec.masks))
    stamps, recorded = rec.masks[camera]
    series, notes, extra = {}, {}, {}
    filt = pose_filter_for(rec, pose_filter)
    fields = {} if filt is None else {"pose_filter": filt}
    if filt is not None:
        extra["pose_filter"] = [filt.position_noise_m, filt.rotation_noise_rad, filt.acceleration_m_s2,
                                filt.angular_acceleration_rad_s2]
    engine = None
    for src in masks:
        fed, reference = rec, None
        if src == "detected":
            from ..perception.stream import StreamDetector, detect_recording
            found = detect_recording(rec, camera, StreamDetector.from_file(detector))
            fed, reference = dataclasses.replace(rec, masks={camera: (stamps, found)}), recorded
            extra["detector"] = _mask_agreement(found, recorded, frames, rec, stamps)
        for t in trackers:
            col = t if src == "recorded" or t == "open_loop" else f"{t}/{src}"
            if col in series:
                continue
            try:
                engine = engine_for(rec, t, **fields)
            except EngineError as e:
                if e.code != INFEASIBLE:
                    raise
                series[col], notes[col] = None, str(e)
                continue
            r = (replay(rec, engine, camera=camera, frames=frames) if t == "open_loop" else   # reads no mask
                 replay(fed, engine, camera=camera, frames=frames, reference=reference))
            series[col] = {"t_s": r.t_s, "iou": r.iou, "observed_px": r.observed_px}
    if ceiling:
        engine = engine if engine is not None else engine_for(rec, "open_loop")
        series["ceiling"] = ceiling_series(rec, path, engine, camera, frames)
    return {"series": series, "unavailable": notes, "iterations": solver_iterations(rec), **extra}


def _last_stamp(rec, frames: int | None) -> int | None:
    """Stamp of the ``frames``-th pose sample (None: no limit), the last mask frame scored."""
    return None if frames is None else int(rec.pose_times_ns[min(frames, len(rec.pose_times_ns)) - 1])


def _mask_agreement(found, recorded, frames, rec, stamps) -> dict:
    """Per mask frame (up to ``frames`` pose samples): IOU of the detected mask against the
    recorded one, and the recorded mask's pixel count."""
    from ..camera import iou as mask_iou
    import torch
    limit = _last_stamp(rec, frames)
    keep = [k for k, s in enumerate(stamps) if limit is None or s <= limit]
    return {"iou": [float(mask_iou(torch.from_numpy(found[k]), torch.from_numpy(np.asarray(recorded[k], bool))))
                    for k in keep],
            "observed_px": [int(np.asarray(recorded[k]).sum()) for k in keep]}


def run(args) -> int:
    from tqdm import tqdm
    trackers = list(dict.fromkeys(args.trackers))
    masks = list(dict.fromkeys(args.masks))
    detector = None
    if "detected" in masks:
        from ..perception.stream import shared_model
        from ..perception.weights import PerceptionModelError
        try:
            _, meta = shared_model(args.detector)          # a bad model file fails here, before any work
        except (PerceptionModelError, OSError) as e:
            raise SystemExit(f"--detector: {e}") from None
        detector = None if args.detector is None else str(args.detector)
        print(f"detector: {args.detector or 'shipped model'} ({meta.get('kind')}, {meta.get('input_type')}, "
              f"{meta.get('fusion')} fusion, threshold {float(meta.get('threshold', 0.5)):.2f})")
    case_list = selected_cases(args, rgb="detected" in masks)
    paths = ensure(case_list, args.data, jobs=args.jobs, progress=not args.no_progress)
    results = []
    work = [(str(p), tuple(trackers), args.frames, args.iterations, tuple(masks), detector, args.pose_filter,
             args.max_correction, args.cut_wall_pairs) for p in paths]
    bar = tqdm(total=len(work), desc="replay", unit="case", disable=args.no_progress)
    for case, path, r in zip(case_list, paths, map_jobs(_evaluate_one, work, args.jobs)):
        bar.update()
        means = {k: series_mean(v, args.min_px) for k, v in r["series"].items()}
        results.append({"case": case.as_dict(), "recording": str(path), "mean_iou": means, **r})
    bar.close()
    columns = columns_for(trackers, masks)
    tab = table(results, columns, args.min_px)
    note = (f"{'quick' if args.quick else 'full'} benchmark, {len(case_list)} cases, trials {args.trials}, "
            f"base seed {args.seed}" + (f", first {args.frames} pose samples" if args.frames else "")
            + model_options_note(args, f" ({_span([r['iterations'] for r in results])} a recording)"
                                 if args.iterations == IMPACT else "")
            + (f", pose filter {args.pose_filter}" if args.pose_filter else "")
            + "; ceiling = the true particles drawn as the model (scoring only)"
            + ("; TRACKER det = corrected with the RGB detector's masks, scored against the recorded masks"
               if "detected" in masks else ""))
    text = format_table(tab, columns, args.min_px, note)
    if "detected" in masks:
        agree = [i for r in results for i, n in zip(r["detector"]["iou"], r["detector"]["observed_px"])
                 if n >= args.min_px]
        text += (f"\ndetector masks vs recorded masks: mean IOU {np.mean(agree):.3f} over {len(agree)} frames "
                 f"with >= {args.min_px} recorded px" if agree else "\ndetector masks: no frame with liquid")
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {"kind": "tracking", "quick": bool(args.quick), "trials": args.trials, "base_seed": args.seed,
           "frames": args.frames, "iterations": args.iterations, "pose_filter": args.pose_filter,
           "max_correction": args.max_correction, "cut_wall_pairs": args.cut_wall_pairs,
           "min_px": args.min_px, "trackers": trackers,
           "masks": masks, "detector": detector, "columns": columns,
           "table": tab, "table_text": text, "cases": results}
    closed = [c for c in columns if c not in ("open_loop", "ceiling") and tab["overall"].get(c) is not None]
    best = max(closed, key=lambda c: tab["overall"][c]) if closed else None
    doc["headline"] = {"name": f"best closed-loop overall IOU ({best or 'no closed-loop tracker run'})",
                       "value": tab["overall"][best] if best else None, "unit": "IOU"}
    save_results(out, doc)
    _plots(out, tab, columns, results, args.min_px)
    return 0


def _span(counts) -> str:
    """"8-11" (or "8") of the solver iterations the recordings ran."""
    got = [c for c in counts if c is not None]
    if not got:
        return "n/a"
    return str(min(got)) if min(got) == max(got) else f"{min(got)}-{max(got)}"


def _evaluate_one(job) -> dict:
    import torch
    torch.set_num_threads(1)
    path, trackers, frames, iterations, masks, detector, pose_filter, max_correction, cut_wall_pairs = job
    return evaluate_case(Path(path), trackers, frames=frames, iterations=iterations, masks=masks,
                         detector=None if detector is None else Path(detector), pose_filter=pose_filter,
                         max_correction=max_correction, cut_wall_pairs=cut_wall_pairs)


def series_mean(s: dict | None, min_px: int) -> float | None:
    """Mean IOU of a per-frame series over frames whose observed mask has >= ``min_px`` px."""
    if s is None:
        return None
    v = [i for i, n in zip(s["iou"], s["observed_px"]) if n >= min_px]
    return float(np.mean(v)) if v else None


def _plots(out: Path, tab: dict, columns: list[str], results: list[dict], min_px: int) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(9, 4))
    width = 0.8 / len(columns)
    for k, c in enumerate(columns):
        vals = [math.nan if tab[r][c] is None else 100 * tab[r][c] for r in ROWS]
        ax.bar(np.arange(len(ROWS)) + (k - (len(columns) - 1) / 2) * width, vals, width, label=LABELS.get(c, c),
               hatch="//" if c == "ceiling" else None, alpha=0.6 if c == "ceiling" else 1.0)
    ax.set_xticks(np.arange(len(ROWS)), ROWS)
    ax.set_ylabel(f"mean IOU, % (frames with >= {min_px} observed px)")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=8, ncols=len(columns))
    ax.set_title("tracking IOU per tracker (thesis Fig. 7.5)")
    fig.tight_layout()
    fig.savefig(out / "table.png", dpi=100)
    plt.close(fig)
    shown = results[:4]
    fig, axes = plt.subplots(len(shown), 1, figsize=(8, 2.2 * len(shown)), squeeze=False)
    for ax, r in zip(axes[:, 0], shown):
        for c in columns:
            s = r["series"].get(c)
            if s is not None:
                ax.plot(s["t_s"], s["iou"], label=LABELS.get(c, c), ls="--" if c == "ceiling" else "-")
        ax.set_title(r["case"]["name"], fontsize=9)
        ax.set_ylim(0, 1)
        ax.set_ylabel("IOU")
    axes[0, 0].legend(fontsize=7, ncols=len(columns))
    axes[-1, 0].set_xlabel("session time, s")
    fig.tight_layout()
    fig.savefig(out / "iou_time.png", dpi=100)
    plt.close(fig)
