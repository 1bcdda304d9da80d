"""``liquidtwin discrepancy REC.mcap [REC2.mcap …] --out DIR``."""

from __future__ import annotations

import argparse
import os
import sys

from .model import CANDIDATES, ENSEMBLE

HELP = ("find what the simulation gets wrong in recordings, name the cause, extend the model and "
        "measure the held-out gain (report.json, report.md, PNGs, model.json)")


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("recordings", nargs="+", metavar="REC.mcap", help="recordings (masks + poses) to analyse")
    p.add_argument("--out", required=True, help="directory for report.json, report.md, model.json and the plots")
    p.add_argument("--camera", default=None, help="camera whose masks to use (default: the first with masks)")
    p.add_argument("--candidates", nargs="+", default=list(CANDIDATES), choices=CANDIDATES, metavar="NAME",
                   help=f"candidates to try (default: all: {' '.join(CANDIDATES)})")
    p.add_argument("--block", type=float, default=0.2, metavar="S",
                   help="time-block length of the fit / held-out split of a single recording, s (default 0.2)")
    p.add_argument("--null-runs", type=int, default=2, metavar="N",
                   help="realisations of the fitted base model for the false-discovery null (default 2; 0: report "
                        "gains only, declare nothing)")
    p.add_argument("--level-runs", type=int, default=None, metavar="N",
                   help="realisations the base model's held-out loss is compared with to call the residual real "
                        "(default 8; the first --null-runs of them are also the candidates' null; one rollout each)")
    p.add_argument("--reference", choices=("base", "best", "median"), default="base",
                   help="what a physics or fill candidate's held-out gains are measured from: the base rollout (base, "
                        "the default), the one of the base model's rollout and realisations that misses least (best), "
                        "or per frame their median loss (median); time and camera offsets re-draw the base rollout and "
                        "are always measured from it. best and median were measured at stop 61 and are off (README)")
    p.add_argument("--ensemble", type=int, default=ENSEMBLE, metavar="K",
                   help="measure the best --top candidates' held-out gains, on the recording and on the null "
                        "realisations, from K jittered draws of the base's and of each candidate's prediction "
                        f"(K rollouts per model; default {ENSEMBLE}; 0: one rollout each, the rule before stop 64)")
    p.add_argument("--score", choices=("distance", "energy"), default="energy",
                   help="how --ensemble's K draws are scored per frame: the energy score, their mean loss less half "
                        "the mean loss between two draws (energy, the default: lowest for the model whose draws spread "
                        "as the liquid does, not for the one that spreads least), or their mean loss (distance)")
    p.add_argument("--null-bar", choices=("magnitude", "spread"), default="spread",
                   help="when the residual is not real, a candidate must beat its null gains' largest (at least 0) "
                        "plus 1.5 x their range (spread, the default: a fit that loses alike on every nothing-hidden "
                        "realisation does not raise the bar) or 1.5 x their largest magnitude (magnitude, the rule "
                        "before stop 64); both + 0.02")
    p.add_argument("--declare-recalibrations", action="store_true",
                   help="also declare a viscosity or cohesion fitted within the calibration's own search range "
                        "(0.75-1.25 x the stated value; the rule before stop 65). By default such a fit is a finer "
                        "calibration, not an effect, and is reported but not declared")
    p.add_argument("--declare-sub-frame-offsets", action="store_true",
                   help="also declare a time offset fitted shorter than one frame period of the camera (the rule "
                        "before stop 66). By default such a fit is reported but not declared: an image is stamped "
                        "once per frame, and physics that starts a pour a little sooner or later fits one")
    p.add_argument("--fill-fit", choices=("mass", "loss"), default="loss",
                   help="what the fill-error fit minimises: the fitting loss as every other candidate (loss, the "
                        "default) or the mismatch of the amount of liquid seen over the fitting frames (mass: tried "
                        "at stop 66, its fits were no nearer the truth); its gains and null check use the losses "
                        "either way")
    p.add_argument("--calibration-draws", type=int, default=0, metavar="K",
                   help="calibrate lambda_v, lambda_c by the mean fitting loss of K jittered draws of each trial's "
                        "prediction instead of its one rollout (K rollouts per trial; default 0: off)")
    p.add_argument("--top", type=int, default=3, metavar="K", help="best candidates checked against the null (default 3)")
    p.add_argument("--no-calibrate", action="store_true", help="keep the base model's lambda_v, lambda_c as stated")
    p.add_argument("--no-stratify", action="store_true",
                   help="resample all held-out time blocks as one set for the gain intervals (default: blocks where "
                        "the source turns and where it rests apart)")
    p.add_argument("--prediction-jitter", type=float, default=0.0, metavar="V",
                   help="start the model's predictions from the fill with this initial-velocity jitter, m/s, one "
                        "fixed draw (default 0; the null realisations use 0.001)")
    p.add_argument("--seed", type=int, default=0, help="seed of the null realisations and the resampling")
    p.add_argument("--jobs", type=int, default=min(4, os.cpu_count() or 1), metavar="N",
                   help="processes running the model evaluations (default: this machine's cores, at most 4; "
                        "the workers run the serial searches, one torch thread each: the report is the one "
                        "--jobs 1 gives on one thread)")
    p.add_argument("--extra-iterations", type=int, default=None, metavar="K",
                   help="solver iterations added to the recordings' stated count (default 2: a real liquid is "
                        "incompressible; an under-converged model biases drag and viscosity fits)")
    p.add_argument("--pose-smoothing", type=float, default=None, metavar="S",
                   help="σ of the zero-phase smoothing of the recorded poses, s (default 0.05; 0: raw poses)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from .analysis import Options, analyse
    try:
        opt = Options(camera=args.camera, candidates=tuple(args.candidates), block_s=args.block,
                      calibrate=not args.no_calibrate, null_runs=args.null_runs, top=args.top, seed=args.seed,
                      stratify=not args.no_stratify, prediction_jitter=args.prediction_jitter,
                      reference=args.reference, ensemble=args.ensemble, score=args.score,
                      null_bar=args.null_bar, recalibrations=args.declare_recalibrations, fill_fit=args.fill_fit,
                      sub_frame_offsets=args.declare_sub_frame_offsets,
                      calibration_draws=args.calibration_draws,
                      jobs=args.jobs, **{k: v for k, v in (("extra_iterations", args.extra_iterations),
                                                            ("pose_smoothing_s", args.pose_smoothing),
                                                            ("level_runs", args.level_runs)) if v is not None})
        report = analyse(args.recordings, args.out, options=opt, progress=not args.no_progress)
    except (ValueError, OSError) as exc:
        print(f"liquidtwin discrepancy: {exc}", file=sys.stderr)
        return 2
    b, e = report["baseline"], report["extended"]
    print(f"decision: {report['decision']}")
    print(f"held-out loss  base {b['heldout_loss']:.3f}  extended ({e['name']}) {e['heldout_loss']:.3f}")
    print(f"held-out IOU   base {b['heldout_iou']:.3f}  extended {e['heldout_iou']:.3f}")
    for c in report["candidates"][:5]:
        g = c["heldout_gain"]
        null = ""
        if c.get("null_gains"):
            null = ("  null gains " + ", ".join(f"{v:+.3f}" for v in c["null_gains"])
                    + " (fitted there " + ", ".join(f"{v:.3g}" for v in c.get("null_fitted") or []) + ")")
        print(f"  {c['name']:<14} fitted {c['value']:.3g}  gain {g['mean']:+.3f} [{g['ci95'][0]:+.3f}, {g['ci95'][1]:+.3f}]"
              f"{null}{'  declared' if c.get('declared') else ''}")
    print(f"report: {args.out}/report.md  ({report['timing_s']['total']:.0f} s)")
    return 0
