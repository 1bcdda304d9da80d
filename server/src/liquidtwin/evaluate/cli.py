"""``liquidtwin evaluate KIND``: the thesis-style evaluations on generated benchmarks.

Each kind lives in its own module of this package exposing ``HELP`` (one line),
``configure(parser)`` and ``run(args) -> exit code``; add it to :data:`KINDS`. Every kind
prints a table, writes JSON (with the seeds) and PNG figures into ``--out``.
"""

from __future__ import annotations

import argparse
import importlib
import math

#: evaluate kind → module (relative to this package).
KINDS = {"tracking": ".tracking", "fill": ".fill", "blockage": ".blockage", "volume": ".volume",
         "discrepancy": ".discrepancy", "sysid": ".sysid", "control": ".control",
         "perception": ".perception"}

HELP = "thesis-style evaluations on generated benchmarks: " + ", ".join(KINDS)


def _module(kind: str):
    return importlib.import_module(KINDS[kind], __package__)


def configure(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="kind", metavar="KIND", required=True)
    for kind in KINDS:
        try:
            mod = _module(kind)
        except ModuleNotFoundError:         # a kind still being written: keep the others usable
            continue
        sp = sub.add_parser(kind, help=mod.HELP, description=mod.HELP)
        mod.configure(sp)


def run(args: argparse.Namespace) -> int:
    return int(_module(args.kind).run(args) or 0)


def add_common(p: argparse.ArgumentParser, *, out: str) -> None:
    """Options every kind shares: data cache, output folder, quick variant, seeds, jobs."""
    from pathlib import Path
    p.add_argument("--data", type=Path, default=Path("eval-data"), metavar="DIR",
                   help="where benchmark recordings are cached (generated when missing; default: %(default)s)")
    p.add_argument("--out", type=Path, default=Path(out), metavar="DIR",
                   help="where the JSON and PNG results go (default: %(default)s)")
    p.add_argument("--quick", action="store_true",
                   help="quick scenes (20 %% of the liquid, 320x240, sped up): minutes instead of hours")
    p.add_argument("--trials", type=int, default=2, metavar="N", help="trials per case (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="base seed of the cases (default: %(default)s)")
    p.add_argument("--jobs", type=int, default=2, metavar="N",
                   help="processes generating recordings (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")


def add_model_options(p: argparse.ArgumentParser) -> None:
    """Options of the model that analyses each recording (kinds that replay recordings)."""
    p.add_argument("--iterations", type=iterations_arg, default=None, metavar="N|impact",
                   help="PBF solver iterations of the analysing model, for the same liquid (default: the "
                        "recording's scene spec; generated recordings: 4 in quick scenes, enough to hold their "
                        "deepest container 90 %% full in full ones). 'impact': per recording, enough to solve "
                        "liquid falling from its highest container rim to its lowest floor (at least the "
                        "stated count; scenes.spec.impact_iterations). A model setting, not the world's truth")
    p.add_argument("--max-correction", type=max_correction_arg, default=None, metavar="S",
                   help="the analysing model moves a particle at most S rest spacings per solver iteration "
                        "(simulation.max_correction_spacings; 0.5 in the control tasks' model: no bursting drops); "
                        "default: uncapped, SPNets as published. A model setting, not the world's truth")
    p.add_argument("--cut-wall-pairs", action="store_true",
                   help="the analysing model cuts the neighbour pairs a wall separates (simulation.cut_wall_pairs, "
                        "as the control tasks' model: no cohesion through walls; ~1.35x the step time); default: "
                        "SPNets' pairs. A model setting, not the world's truth")


IMPACT = "impact"


def iterations_arg(text: str):
    """argparse type of ``--iterations``: a whole number >= 1, or ``impact``."""
    if text == IMPACT:
        return IMPACT
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"takes a whole number >= 1 or '{IMPACT}', got {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"takes a whole number >= 1 or '{IMPACT}', got {text!r}")
    return n


def max_correction_arg(text: str) -> float:
    """argparse type of ``--max-correction``: a number of rest spacings > 0."""
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"takes a number of rest spacings > 0, got {text!r}")
    return v


def model_options_note(args, iterations_detail: str = "") -> str:
    """The table notes' words for :func:`add_model_options` (``iterations_detail`` follows the
    iterations, e.g. the counts ``impact`` gave)."""
    return ((f", model solver iterations {args.iterations}{iterations_detail}" if args.iterations else "")
            + (f", model moves capped at {args.max_correction:g} spacings" if args.max_correction else "")
            + (", model pairs cut at walls" if args.cut_wall_pairs else ""))


def add_likelihood_options(p: argparse.ArgumentParser, *, batched: str = "yes", slack: float = 16.0,
                           blur: float = 0.0) -> None:
    """Options of the δ-likelihood that scores hypothesis banks (fill, blockage); ``batched``,
    ``slack``, ``blur``: this command's defaults (giving one of --slack/--blur sets the other to 0)."""
    p.add_argument("--delta", type=float, default=None, metavar="D",
                   help="pixel agreement probability of the likelihood (default: SPEC's 0.50001)")
    p.add_argument("--slack", type=float, default=None, metavar="PX",
                   help="a pixel's label agrees when the other mask has it within PX pixels, at 640x480 and scaled "
                        f"with the image (default: {slack:g}; 0 with --blur 0: SPEC's exact pixels)")
    p.add_argument("--blur", type=float, default=None, metavar="PX",
                   help="compare the masks smoothed by a Gaussian of sigma PX pixels, at 640x480 and scaled with the "
                        f"image: charges missing liquid in full, forgives drops drawn a few px off (default: {blur:g}; "
                        "0 with --slack 0: SPEC's exact pixels)")
    p.set_defaults(slack_default=slack, blur_default=blur)
    p.add_argument("--batched", choices=("yes", "no"), default=batched,
                   help="simulate the hypotheses together (yes) or one after another (no); the same physics, but "
                        "each hypothesis of a batch runs at its own place, so float rounding (and then a chaotic "
                        f"stream) can differ between hypotheses that are otherwise identical (default: {batched})")


def likelihood_options(args) -> tuple[float, float, float]:
    """(delta, slack_px, blur_px) from :func:`add_likelihood_options`' options, checked."""
    from ..inference import DELTA
    from ..inference.likelihood import check_comparison, check_delta
    delta = DELTA if args.delta is None else args.delta
    if args.slack is None and args.blur is None:
        slack, blur = args.slack_default, args.blur_default
    else:
        slack, blur = args.slack or 0.0, args.blur or 0.0
    try:
        check_delta(delta)
        check_comparison(slack, blur)
    except ValueError as e:
        raise SystemExit(f"--delta/--slack/--blur: {e}") from None
    return delta, slack, blur


def solver_iterations(rec) -> int | None:
    """The solver iterations ``rec``'s model runs (after :func:`with_model_options`); None
    without a scene spec."""
    if rec.spec is None:
        return None
    from ..scenes.spec import simulation_settings
    return int(simulation_settings(rec.spec)["iterations"])


def with_model_options(rec, iterations: int | str | None, max_correction: float | None = None,
                       cut_wall_pairs: bool = False):
    """``rec`` with its scene spec solving ``iterations`` solver iterations of the same liquid
    (``scenes.spec.solve_with``; None: unchanged; ``"impact"``: ``scenes.spec.impact_iterations``
    of its own scene), each iteration's move capped at ``max_correction`` rest spacings (None:
    as the spec says) and, with ``cut_wall_pairs``, no neighbour pairs through walls."""
    if max_correction is not None:
        try:
            max_correction = max_correction_arg(str(max_correction))     # True, 0, NaN: refused
        except argparse.ArgumentTypeError as e:
            raise SystemExit(f"--max-correction {e}") from None
    if rec.spec is not None:
        if max_correction is not None:
            rec.spec.simulation.max_correction_spacings = max_correction
        if cut_wall_pairs:
            rec.spec.simulation.cut_wall_pairs = True
    if iterations is not None:
        if iterations != IMPACT and (isinstance(iterations, (bool, str)) or int(iterations) != iterations
                                     or iterations < 1):
            raise SystemExit(f"--iterations must be a whole number >= 1 or '{IMPACT}', got {iterations!r}")
        if rec.spec is not None:
            from ..scenes.spec import impact_iterations, solve_with
            solve_with(rec.spec, impact_iterations(rec.spec) if iterations == IMPACT else int(iterations))
    return rec


CASES_HELP = ("only these cases: N (the first N) or A:B (cases A to B-1 of the benchmark's fixed order, "
              "which keep their seeds and so their cached recordings)")


def case_range(text: str) -> slice:
    """argparse type of ``--cases``: ``N`` → the first N cases, ``A:B`` → cases A … B−1."""
    try:
        lo, hi = text.split(":", 1) if ":" in text else ("0", text)
        lo, hi = int(lo or 0), int(hi)
    except ValueError:
        raise argparse.ArgumentTypeError(f"takes N or A:B (case numbers), got {text!r}") from None
    if not 0 <= lo < hi:
        raise argparse.ArgumentTypeError(f"takes N >= 1 or A:B with 0 <= A < B, got {text!r}")
    return slice(lo, hi)


def selected_cases(args, **kw) -> list:
    """The benchmark cases the common options select (``--quick/--trials/--seed``, then the
    ``--cases`` range, :func:`case_range`); checks ``--frames``. ``kw`` go to ``cases``."""
    from .benchmark import cases
    case_list = cases(quick=args.quick, trials=args.trials, base_seed=args.seed, **kw)
    picked = getattr(args, "cases", None)
    if picked is not None:
        if picked.start >= len(case_list):
            raise SystemExit(f"--cases: the benchmark has {len(case_list)} cases (0-{len(case_list) - 1})")
        case_list = case_list[picked]
    frames = getattr(args, "frames", None)
    if frames is not None and frames < 2:
        raise SystemExit("--frames must be at least 2")
    return case_list


def save_results(out, doc: dict):
    """Write ``doc`` as ``out/results.json`` (folder created) and, once it has its
    ``headline`` ({"name", "value", "unit"}: the one figure the issue's target is about), as
    ``out/KIND.json`` too (ARCHITECTURE.md); returns the folder as a Path."""
    import json
    from pathlib import Path
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    text = json.dumps(doc, indent=1, default=float) + "\n"
    (out / "results.json").write_text(text)
    if "headline" in doc:
        (out / f"{doc['kind']}.json").write_text(text)
    return out
