"""``liquidtwin evaluate discrepancy``: blind hidden-effect benchmark of discrepancy discovery.

For every canonical effect (and for nothing hidden) ``--trials`` recordings are generated,
each with its own seed: a pour (hold or partial, cup or mug, 90 % full, target drawn by the
seed), the world's fluid parameters jittered, noisy masks and poses, and the effect's
magnitude drawn by the generator from its realistic range. ``discrepancy.analyse`` reads each
recording only; the scoring here then opens the truth sidecar to compare. Printed: the
confusion matrix (planted × named), per class the share named right, the fitted parameter's
relative error when right, and how often the held-out gain's 95 % interval is above zero.
Written: ``results.json`` and ``discrepancy.json`` (with the ``headline``: share named right),
``confusion.png``, and each recording's report under ``reports/``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .benchmark import generate_all, missing_from
from .cli import add_common, save_results
from ..discrepancy.model import ENSEMBLE
from ..procs import map_jobs

HELP = "blind hidden-effect benchmark of discrepancy discovery: confusion matrix and parameter errors"
PARAM_TOLERANCE = 0.25


def _classes() -> tuple:
    from ..discrepancy import CANDIDATES
    return ("none",) + CANDIDATES


@dataclass(frozen=True)
class DiscCase:
    """One recording: ``planted`` effect (or "none"), its trial, seed and scene."""

    planted: str
    trial: int
    seed: int
    quick: bool
    kind: str
    source: str

    @property
    def name(self) -> str:
        return f"disc-{self.planted}-{self.kind}-{self.source}-t{self.trial}-s{self.seed}-{'q' if self.quick else 'f'}"

    def as_dict(self) -> dict:
        return asdict(self) | {"name": self.name}


def disc_cases(*, quick: bool, trials: int, base_seed: int = 0, classes=None) -> list[DiscCase]:
    """Seeds ``base_seed + 100·class + trial``; hold/partial and cup/mug alternate over the
    classes and trials (k = class + trial: hold, partial, hold, partial … with cup, cup, mug,
    mug …). ``class`` is the planted class's place among all of them (:func:`_classes`), so a
    run of a few ``classes`` analyses the very recordings the full run does."""
    out = []
    every = _classes()
    for planted in classes or every:
        i = every.index(planted)
        for t in range(trials):
            seed = base_seed + 100 * i + t
            k = i + t
            out.append(DiscCase(planted, t, seed, quick, ("hold", "partial")[k % 2], ("cup", "mug")[(k // 2) % 2]))
    return out


def _generate(args) -> str:
    case_d, data = args
    import torch
    torch.set_num_threads(1)
    from ..generate import generate
    case = DiscCase(**{k: v for k, v in case_d.items() if k != "name"})
    out = Path(data) / f"{case.name}.mcap"
    effects = [] if case.planted == "none" else [(case.planted, None)]
    generate(f"pour_{case.kind}", out, effects=effects, seed=case.seed, quick=case.quick,
             choices={"source": case.source, "fraction": 0.9})
    out.with_suffix(".case.json").write_text(json.dumps(case.as_dict(), indent=2) + "\n")
    return str(out)


def _analyse(job) -> dict:
    path, out, opts = job
    import torch
    torch.set_num_threads(1)
    from ..discrepancy import Options, analyse
    rep = analyse([path], out, options=Options(**opts))
    keep = ("decision", "baseline", "extended", "reference", "null", "timing_s", "evaluations", "stated_params", "frame_s")
    return {k: rep[k] for k in keep} | {"candidates": [{k: c.get(k) for k in ("name", "params", "value", "best_tried", "tied",
                                                                              "heldout_gain", "single_rollout_gain", "reference",
                                                                              "null_gains", "null_fitted", "declared",
                                                                              "recalibration", "not_declared", "trace",
                                                                              "fit_objective", "evidence", "sub_frame")}
                                                         for c in rep["candidates"]]}


def configure(p) -> None:
    add_common(p, out="eval-discrepancy")
    p.set_defaults(trials=1)
    p.add_argument("--classes", nargs="+", default=None, metavar="NAME",
                   help="planted classes to run (default: none and every candidate)")
    p.add_argument("--null-runs", type=int, default=2, metavar="N", help="null realisations per analysis (default 2)")
    p.add_argument("--no-calibrate", action="store_true",
                   help="keep the recordings' stated lambda_v, lambda_c (no calibration step; for comparison)")
    p.add_argument("--no-stratify", action="store_true",
                   help="resample all held-out blocks as one set for the gain intervals (the rule before stop 59; "
                        "for comparison)")
    p.add_argument("--reference", choices=("base", "best", "median"), default="base",
                   help="what the analyses measure held-out gains from (default base; see liquidtwin "
                        "discrepancy --help)")
    p.add_argument("--ensemble", type=int, default=ENSEMBLE, metavar="K",
                   help="the analyses measure the best candidates' gains from K jittered draws of each prediction "
                        f"(default {ENSEMBLE}; 0: one rollout each; see liquidtwin discrepancy --help)")
    p.add_argument("--score", choices=("distance", "energy"), default="energy",
                   help="how the analyses score --ensemble's draws (default energy; see liquidtwin discrepancy "
                        "--help)")
    p.add_argument("--null-bar", choices=("magnitude", "spread"), default="spread",
                   help="how the analyses' null gains set a candidate's bar when the residual is not real (default "
                        "spread; see liquidtwin discrepancy --help)")
    p.add_argument("--declare-recalibrations", action="store_true",
                   help="the analyses also declare a viscosity or cohesion fitted within the calibration's search "
                        "range (the rule before stop 65; see liquidtwin discrepancy --help)")
    p.add_argument("--declare-sub-frame-offsets", action="store_true",
                   help="the analyses also declare a time offset shorter than one frame period (the rule before "
                        "stop 66; see liquidtwin discrepancy --help)")
    p.add_argument("--fill-fit", choices=("mass", "loss"), default="loss",
                   help="what the analyses' fill-error fits minimise (default loss; mass: the amount of liquid seen, "
                        "tried at stop 66; see liquidtwin discrepancy --help)")
    p.add_argument("--calibration-draws", type=int, default=0, metavar="K",
                   help="the analyses calibrate lambda_v, lambda_c from K jittered draws of each trial "
                        "(default 0: off; see liquidtwin discrepancy --help)")
    p.add_argument("--prediction-jitter", type=float, default=0.0, metavar="V",
                   help="the analyses start the model's predictions with this initial-velocity jitter, m/s "
                        "(default 0; see liquidtwin discrepancy --help)")


def score(case: DiscCase, truth: dict, result: dict) -> dict:
    """Compare one analysis with its truth sidecar (the only place the truth is read)."""
    eff = truth.get("effect")
    planted = eff["name"] if eff else "none"
    named = result["decision"]
    row = {"planted": planted, "named": named, "correct": named == planted, "truth_value": eff["value"] if eff else None}
    if eff and named == planted:
        cand = next(c for c in result["candidates"] if c["name"] == named)
        row["fitted_value"] = cand["value"]
        row["rel_error"] = abs(cand["value"] - eff["value"]) / abs(eff["value"])
        if cand.get("best_tried") is not None:      # the best point tried, for comparison
            row["rel_error_best_tried"] = abs(cand["best_tried"] - eff["value"]) / abs(eff["value"])
        row["gain_ci95"] = cand["heldout_gain"]["ci95"]
        row["identified"] = identified(cand)
    return row


def identified(cand: dict) -> bool:
    """Whether a fit names its value: the tried values with the same best fitting loss (``tied``)
    span no more than ±PARAM_TOLERANCE of it. A blockage fraction that ties from 0.4 to 1.0 is
    not identified, however close its point value (the first of the ties) happens to be."""
    tied = cand.get("tied")
    return not tied or tied[1] - tied[0] <= 2.0 * PARAM_TOLERANCE * abs(cand["value"])


def hit(row: dict) -> bool:
    """One run as the issue counts it: the planted class named and, for an effect, its fit within
    ``PARAM_TOLERANCE`` of the truth (identified) with its held-out gain interval above zero."""
    if not row["correct"]:
        return False
    if row["planted"] == "none":
        return True
    return (row.get("rel_error", math.inf) <= PARAM_TOLERANCE and row.get("identified", True)
            and bool(row.get("gain_ci95")) and row["gain_ci95"][0] > 0)


def table(rows: list) -> dict:
    classes = list(_classes())
    named = classes + ["unexplained"]
    conf = {p: {n: 0 for n in named} for p in classes}
    per = {}
    for r in rows:
        conf[r["planted"]][r["named"]] += 1
    for p in classes:
        rs = [r for r in rows if r["planted"] == p]
        if not rs:
            continue
        errs = [r["rel_error"] for r in rs if "rel_error" in r]
        tried = [r["rel_error_best_tried"] for r in rs if "rel_error_best_tried" in r]
        per[p] = {"runs": len(rs), "correct": sum(r["correct"] for r in rs),
                  "median_rel_error": float(np.median(errs)) if errs else None,
                  "within_25pct": sum(r["rel_error"] <= PARAM_TOLERANCE and r.get("identified", True)
                                      for r in rs if "rel_error" in r),
                  "not_identified": sum(1 for r in rs if r.get("identified") is False),
                  "median_rel_error_best_tried": float(np.median(tried)) if tried else None,
                  "gain_ci_above_0": sum(1 for r in rs if r.get("gain_ci95") and r["gain_ci95"][0] > 0),
                  "hits": sum(hit(r) for r in rs)}
    total = sum(v["runs"] for v in per.values())
    right = sum(v["correct"] for v in per.values())
    return {"confusion": conf, "per_class": per, "correct": right, "runs": total}


def format_table(tab: dict, note: str) -> str:
    classes = [p for p in tab["confusion"] if p in tab["per_class"]]
    named = list(next(iter(tab["confusion"].values())))
    short = {n: n[:6] for n in named}
    lines = ["planted \\ named".ljust(16) + " ".join(f"{short[n]:>6}" for n in named)]
    for p in classes:
        lines.append(f"{p:<16}" + " ".join(f"{tab['confusion'][p][n] or '.':>6}" for n in named))
    lines += ["", f"{'class':<16}{'right':>8}{'param err (median)':>20}{'within 25 %':>13}{'gain CI > 0':>13}"
                  f"{'best tried err':>16}{'not identified':>16}"]
    pct = (lambda e: "—" if e is None else f"{100 * e:.0f} %")
    for p in classes:
        v = tab["per_class"][p]
        lines.append(f"{p:<16}{v['correct']:>4}/{v['runs']:<3}{pct(v['median_rel_error']):>20}{v['within_25pct']:>13}"
                     f"{v['gain_ci_above_0']:>13}{pct(v.get('median_rel_error_best_tried')):>16}"
                     f"{v.get('not_identified', 0):>16}")
    lines += ["", f"named right: {tab['correct']}/{tab['runs']}", note]
    return "\n".join(lines)


def run(args) -> int:
    from tqdm import tqdm
    classes = tuple(args.classes) if args.classes else _classes()
    bad = [c for c in classes if c not in _classes()]
    if bad:
        raise SystemExit(f"unknown class(es) {bad}; known: {', '.join(_classes())}")
    if args.trials < 1:
        raise SystemExit("--trials must be at least 1")
    opts = {"null_runs": args.null_runs, "calibrate": not args.no_calibrate, "stratify": not args.no_stratify,
            "prediction_jitter": args.prediction_jitter, "reference": args.reference, "ensemble": args.ensemble,
            "calibration_draws": args.calibration_draws, "score": args.score,
            "null_bar": args.null_bar, "recalibrations": args.declare_recalibrations, "fill_fit": args.fill_fit,
            "sub_frame_offsets": args.declare_sub_frame_offsets}
    from ..discrepancy import Options
    try:
        Options(**opts)                 # a bad combination stops here, before any recording is made
    except ValueError as exc:
        raise SystemExit(f"liquidtwin evaluate discrepancy: {exc}") from None
    case_list = disc_cases(quick=args.quick, trials=args.trials, base_seed=args.seed, classes=classes)
    data = Path(args.data)
    data.mkdir(parents=True, exist_ok=True)
    missing = [case_list[i] for i in missing_from([data / f"{c.name}.mcap" for c in case_list],
                                                  progress=not args.no_progress)]
    generate_all(_generate, [(c.as_dict(), str(data)) for c in missing], jobs=args.jobs,
                 desc="generate", progress=not args.no_progress)
    out = Path(args.out)
    work = [(str(data / f"{c.name}.mcap"), str(out / "reports" / c.name), opts) for c in case_list]
    rows = []
    bar = tqdm(total=len(work), desc="discrepancy", unit="rec", disable=args.no_progress)
    for case, res in zip(case_list, map_jobs(_analyse, work, args.jobs)):
        truth = json.loads((data / f"{case.name}.truth.json").read_text())
        rows.append(score(case, truth, res) | {"case": case.as_dict(), "timing_s": res["timing_s"],
                                               "baseline": res["baseline"], "extended": res["extended"],
                                               "reference": res["reference"], "null": res["null"],
                                               "stated_params": res["stated_params"], "frame_s": res["frame_s"],
                                               "candidates": res["candidates"]})
        bar.update()
    bar.close()
    tab = table(rows)
    t = [r["timing_s"]["total"] for r in rows]
    settings = [f"null runs {args.null_runs}"]
    settings += ["not calibrated"] if args.no_calibrate else []
    settings += ["intervals not stratified"] if args.no_stratify else []
    settings += [f"predictions jittered {args.prediction_jitter:g} m/s"] if args.prediction_jitter else []
    settings += [f"gains from the {args.reference} reference"] if args.reference != "base" else []
    # the score is used only on an ensemble's draws (Options.score)
    settings += ([f"the best gains from {args.ensemble} draws, {args.score} scores"] if args.ensemble
                 else ["gains from one rollout each"])
    settings += [f"{args.null_bar} null bar"]
    settings += ["recalibrations declared"] if args.declare_recalibrations else []
    settings += ["fill errors fitted by the amount of liquid"] if args.fill_fit == "mass" else []
    settings += ["sub-frame time offsets declared"] if args.declare_sub_frame_offsets else []
    settings += [f"calibrated on {args.calibration_draws} draws"] if args.calibration_draws else []
    note = (f"{'quick' if args.quick else 'full'} scenes, {args.trials} trial(s) per class, base seed {args.seed}, "
            f"{'; '.join(settings)}; analysis time per recording median {np.median(t):.0f} s (max {max(t):.0f} s)")
    text = format_table(tab, note)
    print(text)
    doc = {"kind": "discrepancy", "quick": bool(args.quick), "trials": args.trials, "base_seed": args.seed,
           "headline": {"name": "hidden effects named right", "value": tab["correct"] / max(tab["runs"], 1),
                        "unit": "share"},
           "table": tab, "table_text": text, "rows": rows}
    save_results(out, doc)
    _plot(out, tab)
    return 0


def _plot(out: Path, tab: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    planted = [p for p in tab["confusion"] if p in tab["per_class"]]
    named = list(next(iter(tab["confusion"].values())))
    m = np.array([[tab["confusion"][p][n] for n in named] for p in planted], float)
    fig, ax = plt.subplots(figsize=(0.55 * len(named) + 2.5, 0.45 * len(planted) + 1.8))
    ax.imshow(m, cmap="Blues")
    for i in range(len(planted)):
        for j in range(len(named)):
            if m[i, j]:
                ax.text(j, i, int(m[i, j]), ha="center", va="center", fontsize=8)
    ax.set_xticks(range(len(named)), named, rotation=60, ha="right", fontsize=8)
    ax.set_yticks(range(len(planted)), planted, fontsize=8)
    ax.set_xlabel("named")
    ax.set_ylabel("planted")
    fig.tight_layout()
    fig.savefig(out / "confusion.png", dpi=110)
    plt.close(fig)
