"""``liquidtwin evaluate volume``: the two volume estimates of a session against the truth (SPEC §5).

Every benchmark recording (:mod:`.benchmark`) is replayed (:func:`.replay.replay`) through one
:class:`~liquidtwin.session.SessionEngine` per tracker. At each mask frame the session reports

- **particles**: particles the container holds × ml per particle (``engine.volumes()``), which
  depends on how well the tracker keeps the particles where the liquid is, and
- **mask**: the model-based estimate from the masks alone (``engine.mask_volumes()``: expected
  masks per volume + histogram filter, :class:`~liquidtwin.session._volumes.MaskVolumes`); it
  does not depend on the tracker, so it is taken from the first tracker's replay. Before a
  mask could first show a container's liquid it reports None; the table then counts the
  spec's stated fill (0 for an empty target), what a user would assume.

Truth (scoring only, the generator's sidecar): true particles a container holds (the engine's
:func:`~liquidtwin.session.engine.held_count` rule on the true state) × the truth's ml per
particle, at the pose sample nearest each mask stamp. Columns: RMSE, ml, of the target and the
source over the **pour** frames (from the first mask frame whose recorded source tilt exceeds
:data:`POUR_TILT_RAD` to the end) and over all mask frames. Results: ``results.json`` (every
case with seed, parameters and series), ``rmse.png`` and ``volume_time.png`` (truth vs both
estimates over time for the first cases).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .benchmark import ensure
from .cli import (CASES_HELP, add_common, add_model_options, case_range, model_options_note, save_results,
                  selected_cases, with_model_options)
from .replay import MODES, engine_for, replay

HELP = "volume estimates (particle count per tracker, model-based from masks) vs truth, RMSE ml (SPEC §5)"
TRACKERS = ("open_loop", "warp_field")
#: The pour starts when the source (recorded pose) tilts more than this from upright, rad.
POUR_TILT_RAD = 0.2
COLUMNS = ("target pour", "target all", "source pour", "source all")


def configure(p) -> None:
    add_common(p, out="eval-volume")
    p.add_argument("--trackers", nargs="+", default=list(TRACKERS), choices=list(MODES), metavar="T",
                   help=f"trackers whose particle-count volume is scored, from {', '.join(MODES)} "
                        f"(default: {' '.join(TRACKERS)})")
    p.add_argument("--cases", type=case_range, default=None, metavar="N|A:B", help=CASES_HELP)
    p.add_argument("--frames", type=int, default=None, metavar="N",
                   help="only the first N pose samples of each recording (default: all)")
    add_model_options(p)


def true_volumes(path: Path, engine, stamps_ns) -> dict:
    """Scoring only: {container: (M,) true ml at each mask stamp} from ``REC.truth.*``."""
    from ..session.engine import held_count
    from ..sim import make_state
    z = np.load(Path(path).with_suffix(".truth.npz"), allow_pickle=False)
    truth = json.loads(Path(path).with_suffix(".truth.json").read_text())
    ml = next(iter(truth["fill_ml"]["reports"].values()))["particle_volume_ml"]
    scene = engine._scene                                  # read only: the objects and SDFs
    out = {n: [] for n in scene.containers}
    for s in stamps_ns:
        j = int(np.argmin(np.abs(z["pose_stamps_ns"] - int(s))))
        state = make_state(z["particles"][j], poses=z["true_poses"][j])
        for n in scene.containers:
            k = scene.names.index(n)
            out[n].append(held_count(scene.model, state, k, scene.objects[k]) * ml)
    return {n: np.array(v) for n, v in out.items()}


def _tilt(pose) -> float:
    x, _, z, _ = np.asarray(pose, float)[3:]
    return math.acos(min(1.0, max(-1.0, 1.0 - 2.0 * (x * x + z * z))))


def pour_from(rec, stamps) -> int:
    """Index of the first of ``stamps`` (ns) at which the recorded source is tilted more than
    :data:`POUR_TILT_RAD` (``len(stamps)`` if never, or if the scene has no source)."""
    if "source" not in rec.object_names:
        return len(stamps)
    src = rec.object_names.index("source")
    return next((i for i, s in enumerate(stamps) if _tilt(rec.poses_at(int(s))[src]) > POUR_TILT_RAD), len(stamps))


def evaluate_case(path: Path, trackers, *, frames: int | None = None, iterations=None,
                  max_correction: float | None = None, cut_wall_pairs: bool = False) -> dict:
    """{"t_s", "truth", "pour_from", "particles": {tracker: {container: [...]}}, "mask": {...},
    "mask_ms"} for one recording; ``iterations``, ``max_correction``, ``cut_wall_pairs``: the
    trackers' model (``cli.with_model_options``; the mask model has none)."""
    from ..recordings import read_recording
    from ..session.errors import INFEASIBLE, EngineError
    rec = with_model_options(read_recording(path, images=False), iterations, max_correction, cut_wall_pairs)
    series, mask, stamps, mask_ms, t_s = {}, None, [], [], []
    engine = None
    for t in trackers:
        try:
            engine = engine_for(rec, t)
        except EngineError as e:            # a mode this build cannot run: n/a in the table
            if e.code != INFEASIBLE:
                raise
            series[t] = None
            continue
        part = {n: [] for n in engine.container_names}
        est = {n: [] for n in engine.container_names}
        first = mask is None
        fills = {f.container: float(f.volume_ml) for f in rec.spec.fills}

        def on_frame(i, eng, corr, part=part, est=est, first=first):
            if corr is None:
                return
            for n, v in eng.volumes().items():
                part[n].append(float(v))
            if first:
                stamps.append(int(rec.pose_times_ns[i]))
                mask_ms.append(float(eng._mask_vol.last_ms))
                for n, v in eng.mask_volumes().items():
                    est[n].append(fills.get(n, 0.0) if v is None else float(v))
        r = replay(rec, engine, frames=frames, on_frame=on_frame)
        series[t] = part
        if first:
            mask, t_s = est, r.t_s
    if engine is None:
        raise SystemExit(f"none of the trackers {', '.join(trackers)} can run here")
    truth = true_volumes(path, engine, stamps)
    return {"t_s": t_s, "truth": {n: v.tolist() for n, v in truth.items()}, "pour_from": pour_from(rec, stamps),
            "particles": series, "mask": mask, "mask_ms": mask_ms}


def _rmse(est, truth, start: int = 0) -> float | None:
    e, t = np.asarray(est, float)[start:], np.asarray(truth, float)[start:]
    return float(np.sqrt(np.mean((e - t) ** 2))) if len(e) else None


def case_rmse(r: dict) -> dict:
    """{estimator: {column: RMSE ml or None}} of one evaluated case."""
    out = {}
    ests = {f"particles {t}": s for t, s in r["particles"].items()} | {"mask": r["mask"]}
    for name, s in ests.items():
        out[name] = {}
        for col in COLUMNS:
            cont, span = col.split()
            if s is None or cont not in s:
                out[name][col] = None
                continue
            out[name][col] = _rmse(s[cont], r["truth"][cont], r["pour_from"] if span == "pour" else 0)
    return out


def table(results: list[dict]) -> dict:
    """{estimator: {column: RMSE ml pooled over every case's frames, or None}}."""
    out = {}
    for name in results[0]["rmse"]:
        out[name] = {}
        for col in COLUMNS:
            cont, span = col.split()
            err = []
            for r in results:
                s = r["particles"].get(name.split()[-1]) if name.startswith("particles") else r["mask"]
                if s is None or cont not in s:
                    continue
                a = r["pour_from"] if span == "pour" else 0
                err += list((np.asarray(s[cont])[a:] - np.asarray(r["truth"][cont])[a:]) ** 2)
            out[name][col] = float(np.sqrt(np.mean(err))) if err else None
    return out


def format_table(tab: dict, note: str) -> str:
    w = 14
    lines = ["estimator".ljust(30) + "".join(c.rjust(w) for c in COLUMNS)]
    for name, row in tab.items():
        lines.append(name.ljust(30) + "".join(("n/a" if row[c] is None else f"{row[c]:.2f} ml").rjust(w)
                                             for c in COLUMNS))
    lines.append(f"RMSE vs the true held volume per mask frame; pour = from the first frame with the source "
                 f"tilted > {POUR_TILT_RAD} rad; {note}")
    return "\n".join(lines)


def run(args) -> int:
    from tqdm import tqdm
    trackers = list(dict.fromkeys(args.trackers))
    case_list = selected_cases(args)
    paths = ensure(case_list, args.data, jobs=args.jobs, progress=not args.no_progress)
    results = []
    for case, path in tqdm(list(zip(case_list, paths)), desc="replay", unit="case", disable=args.no_progress):
        r = evaluate_case(path, trackers, frames=args.frames, iterations=args.iterations,
                          max_correction=args.max_correction, cut_wall_pairs=args.cut_wall_pairs)
        r = {"case": case.as_dict(), "recording": str(path), **r}
        r["rmse"] = case_rmse(r)
        results.append(r)
    tab = table(results)
    note = (f"{'quick' if args.quick else 'full'} benchmark, {len(case_list)} cases, trials {args.trials}, "
            f"base seed {args.seed}" + (f", first {args.frames} pose samples" if args.frames else "")
            + model_options_note(args))
    text = format_table(tab, note)
    print(text)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {"kind": "volume", "quick": bool(args.quick), "trials": args.trials, "base_seed": args.seed,
           "frames": args.frames, "iterations": args.iterations, "max_correction": args.max_correction,
           "cut_wall_pairs": args.cut_wall_pairs,
           "trackers": trackers, "pour_tilt_rad": POUR_TILT_RAD, "columns": list(COLUMNS),
           "table": tab, "table_text": text, "cases": results}
    col = next((c for c in COLUMNS if c.startswith("target") and c.endswith("pour")), None)
    rows = {k: v[col] for k, v in tab.items() if col and v.get(col) is not None}
    best = min(rows, key=rows.get) if rows else None       # None: no frame of a pour was evaluated
    doc["headline"] = {"name": f"target-container RMSE during pours ({best or 'no pour frames'})",
                       "value": rows.get(best), "unit": "ml"}
    save_results(out, doc)
    _plots(out, tab, results)
    return 0


def _plots(out: Path, tab: dict, results: list[dict]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 3.5))
    names = list(tab)
    width = 0.8 / len(names)
    for k, n in enumerate(names):
        vals = [math.nan if tab[n][c] is None else tab[n][c] for c in COLUMNS]
        ax.bar(np.arange(len(COLUMNS)) + (k - (len(names) - 1) / 2) * width, vals, width, label=n)
    ax.axhline(10.0, color="k", lw=0.8, ls=":")
    ax.set_xticks(np.arange(len(COLUMNS)), COLUMNS)
    ax.set_ylabel("RMSE, ml")
    ax.legend(fontsize=8)
    ax.set_title("volume estimates vs truth (dotted: the 10 ml target)")
    fig.tight_layout()
    fig.savefig(out / "rmse.png", dpi=100)
    plt.close(fig)
    shown = results[:4]
    fig, axes = plt.subplots(len(shown), 1, figsize=(8, 2.4 * len(shown)), squeeze=False)
    for ax, r in zip(axes[:, 0], shown):
        t = r["t_s"]
        ax.plot(t, r["truth"]["target"], "k-", lw=2, label="truth")
        for tr, s in r["particles"].items():
            if s is None:
                continue
            ax.plot(t, s["target"], "-", label=f"particles ({tr})")
        ax.plot(t, r["mask"]["target"], "--", label="mask (model-based)")
        if r["pour_from"] < len(t):
            ax.axvline(t[r["pour_from"]], color="grey", lw=0.8, ls=":")
        ax.set_title(f"{r['case']['name']}: target", fontsize=9)
        ax.set_ylabel("ml")
    axes[0, 0].legend(fontsize=7, ncols=4)
    axes[-1, 0].set_xlabel("session time, s")
    fig.tight_layout()
    fig.savefig(out / "volume_time.png", dpi=100)
    plt.close(fig)
