"""``liquidtwin evaluate fill``: how full was the source? — the thesis's Fig. 7.6 on generated pours.

Cases: the shared pouring benchmark (:mod:`.benchmark`) with fills empty, 30, 60, 90 % —
cup and bottle × partial/hold/dump × trials, each with jittered world parameters, sensor
noise and one mild effect. Each recording is analysed blind by
:func:`liquidtwin.inference.infer_fill` (the four fill hypotheses simulated together, scored
with the δ-likelihood of SPEC §3 on masks blurred by ``--blur`` px), open loop and warp-field tracked. Quick scenes hold
``generate.catalog.QUICK_FILL`` of the full scenes' liquid, so their hypotheses are scaled
the same way (configuration, not truth). Scoring reads the case's true fill from the case
list (``REC.case.json``).

Table: per sequence and tracker the probability on each hypothesis (truth marked *); per
tracker the mean probability on the truth and how often the truth ranks first; a Fig. 7.6
panel per true fill (mean distribution). Results: ``results.json``, ``fill.png``,
``fill_time.png``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..inference.likelihood import FILL_BLUR_PX, FILL_RADIUS_SCALE
from .benchmark import ensure
from .cli import (CASES_HELP, add_common, add_likelihood_options, add_model_options, case_range,
                  likelihood_options, model_options_note, save_results, selected_cases, solver_iterations,
                  with_model_options)

HELP = "initial-fill inference (empty/30/60/90 %) on the pouring benchmark (thesis Fig. 7.6)"
FILLS = (0.0, 0.3, 0.6, 0.9)
MODES = ("open_loop", "warp_field")


def configure(p) -> None:
    add_common(p, out="eval-fill")
    add_model_options(p)
    p.add_argument("--trackers", nargs="+", default=list(MODES), choices=["open_loop", "warp_field", "map_filter"],
                   metavar="T", help="scoring modes to compare (default: open_loop warp_field)")
    p.add_argument("--sources", nargs="+", default=["cup", "bottle"], choices=["cup", "bottle"], metavar="S",
                   help="source containers (default: cup bottle)")
    p.add_argument("--kinds", nargs="+", default=["partial", "hold", "dump"], choices=["partial", "hold", "dump"],
                   metavar="K", help="pour trajectories (default: partial hold dump)")
    p.add_argument("--cases", type=case_range, default=None, metavar="N|A:B", help=CASES_HELP)
    p.add_argument("--frames", type=int, default=None, metavar="N",
                   help="only the first N pose samples of each recording (default: all)")
    add_likelihood_options(p, slack=0.0, blur=FILL_BLUR_PX)
    p.add_argument("--radius-scale", type=float, default=FILL_RADIUS_SCALE, metavar="S",
                   help="draw the hypotheses' particles as discs of S x their projected radius in px "
                        f"(default: {FILL_RADIUS_SCALE:g}; 1: as sessions draw them)")


def run(args) -> int:
    from tqdm import tqdm
    from ..generate.catalog import QUICK_FILL
    from ..inference import fill_name, infer_fill
    from ..recordings import read_recording
    delta, slack, blur = likelihood_options(args)
    from ..inference.likelihood import check_radius_scale
    try:
        check_radius_scale(args.radius_scale)
    except ValueError as e:
        raise SystemExit(f"--radius-scale: {e}") from None
    case_list = selected_cases(args, sources=tuple(args.sources), fills=FILLS, kinds=tuple(args.kinds))
    paths = ensure(case_list, args.data, jobs=args.jobs, progress=not args.no_progress)
    scale = QUICK_FILL if args.quick else 1.0
    names = [fill_name(f) for f in FILLS]
    results = []
    for case, path in tqdm(list(zip(case_list, paths)), desc="infer", unit="rec", disable=args.no_progress):
        rec = with_model_options(read_recording(path, images=False), args.iterations, args.max_correction,
                                 args.cut_wall_pairs)
        truth = fill_name(case.fraction)                          # scoring only
        row = {"case": case.as_dict(), "recording": str(path), "truth": truth, "modes": {},
               "iterations": solver_iterations(rec)}
        for mode in args.trackers:
            post = infer_fill(rec, fractions=FILLS, tracking=mode, scale=scale, frames=args.frames, delta=delta,
                              slack_px=slack, blur_px=blur, batched=args.batched == "yes",
                              radius_scale=args.radius_scale)
            k = post.names.index(truth)
            row["modes"][mode] = post.as_dict() | {"correct": post.best == truth, "p_truth": float(post.probability[k])}
        results.append(row)
        _save(args, {"kind": "fill", "partial": True, "cases": results})        # survives an interruption
    summary = {m: {"mean_p_truth": float(np.mean([r["modes"][m]["p_truth"] for r in results])),
                   "ranked_first": int(sum(r["modes"][m]["correct"] for r in results)), "sequences": len(results)}
               for m in args.trackers}
    text = format_table(results, args.trackers, names, summary, args.quick, delta, slack, blur, args)
    print(text)
    doc = {"kind": "fill", "quick": bool(args.quick), "trials": args.trials, "base_seed": args.seed, "delta": delta,
           "slack_px": slack, "blur_px": blur, "radius_scale": args.radius_scale,
           "iterations": args.iterations,
           "max_correction": args.max_correction, "cut_wall_pairs": args.cut_wall_pairs,
           "scale": scale, "frames": args.frames, "trackers": list(args.trackers), "hypotheses": names,
           "summary": summary, "table_text": text, "cases": results}
    best = max(summary, key=lambda m: summary[m]["mean_p_truth"])
    doc["headline"] = {"name": f"mean probability of the true fill ({best})", "value": summary[best]["mean_p_truth"],
                       "unit": "probability"}
    out = _save(args, doc)
    _plots(out, results, args.trackers, names)
    return 0


def _save(args, doc: dict) -> Path:
    return save_results(args.out, doc)


def format_table(results, modes, names, summary, quick, delta, slack, blur, args) -> str:
    lines = []
    for mode in modes:
        lines.append(f"[{mode}]  probability per hypothesis (* = true fill)")
        lines.append("sequence".ljust(28) + "".join(n.rjust(9) for n in names) + "  first")
        for r in results:
            m = r["modes"][mode]
            cells = [(f"{p:.3f}" + ("*" if n == r["truth"] else " ")).rjust(9) for n, p in zip(m["names"], m["probability"])]
            lines.append(r["case"]["name"][:27].ljust(28) + "".join(cells) + ("yes" if m["correct"] else "no").rjust(7))
        s = summary[mode]
        lines.append(f"mean probability on the truth {s['mean_p_truth']:.3f}; truth ranked first "
                     f"{s['ranked_first']}/{s['sequences']}")
    lines.append(f"{'quick' if quick else 'full'} benchmark, trials {args.trials}, base seed {args.seed}, "
                 f"delta = {delta}, slack {slack:g} px, blur {blur:g} px at 640x480, "
                 f"particles drawn at {args.radius_scale:g} x their radius"
                 + (f", first {args.frames} pose samples" if args.frames else "")
                 + model_options_note(args))
    return "\n".join(lines)


def _plots(out: Path, results, modes, names) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(names), figsize=(3.2 * len(names), 3), squeeze=False)
    width = 0.8 / len(modes)
    for ax, truth in zip(axes[0], names):
        rows = [r for r in results if r["truth"] == truth]
        for j, mode in enumerate(modes):
            mean = np.mean([r["modes"][mode]["probability"] for r in rows], 0) if rows else np.zeros(len(names))
            ax.bar(np.arange(len(names)) + (j - (len(modes) - 1) / 2) * width, mean, width, label=mode)
        ax.set_xticks(np.arange(len(names)), [n + ("*" if n == truth else "") for n in names], fontsize=8)
        ax.set_ylim(0, 1)
        ax.set_title(f"true fill {truth} ({len(rows)} seq.)", fontsize=9)
    axes[0, 0].set_ylabel("mean probability")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "fill.png", dpi=90)
    plt.close(fig)
    shown = results[:8]
    fig, axes = plt.subplots(len(shown), len(modes), figsize=(5 * len(modes), 1.9 * len(shown)), squeeze=False)
    for i, r in enumerate(shown):
        for j, mode in enumerate(modes):
            m, ax = r["modes"][mode], axes[i, j]
            over = np.asarray(m["probability_over_time"])
            for k, n in enumerate(m["names"]):
                ax.plot(m["times_s"], over[:, k] if len(over) else [], label=n, lw=2.5 if n == r["truth"] else 1.0)
            ax.set_ylim(-0.02, 1.02)
            ax.set_title(f"{r['case']['name']} — {mode}", fontsize=8)
    axes[0, 0].legend(fontsize=7, ncols=4)
    fig.tight_layout()
    fig.savefig(out / "fill_time.png", dpi=80)
    plt.close(fig)
