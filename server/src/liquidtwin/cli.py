"""``liquidtwin``: the server package's command line.

Subcommands live in :data:`COMMANDS` (name → :class:`Command`); add a new one there. A
command either configures its own argparse sub-parser (``configure``) and runs with the
parsed namespace, or is a *pass-through* that receives the raw arguments after its name
and parses them itself (``bench``, whose module owns its options).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable


@dataclass(frozen=True)
class Command:
    """One ``liquidtwin`` subcommand.

    Attributes:
      help: one line for ``liquidtwin --help``.
      run: ``run(args) -> exit code``; args is the parsed namespace, or the list of raw
        arguments for a pass-through command.
      configure: adds the command's arguments to its sub-parser (None for pass-through).
      passthrough: hand the raw arguments after the command name to ``run``.
    """

    help: str
    run: Callable
    configure: Callable[[argparse.ArgumentParser], None] | None = None
    passthrough: bool = False


# ------------------------------------------------------------------ demo

def _demo_configure(p: argparse.ArgumentParser) -> None:
    from .demo import configure
    configure(p)


def _demo_run(args: argparse.Namespace) -> int:
    from .demo import run
    return run(args)


def run_demo(args: argparse.Namespace) -> int:
    """Simulate the cup→bowl pour, record it to MCAP, print a summary table."""
    import torch
    from tqdm import tqdm

    from .record import Recorder
    from .scenes.pour import build_pour_scene, liquid_volumes
    from .sim import step

    if args.every < 1:
        raise SystemExit("liquidtwin demo: --every must be >= 1")
    if args.seconds is not None and not args.seconds > 0:
        raise SystemExit("liquidtwin demo: --seconds must be > 0")
    if args.threads > 0:
        torch.set_num_threads(args.threads)

    t_total = time.perf_counter()
    scene = build_pour_scene(seconds=args.seconds, particles_scale=args.particles_scale,
                             backend=args.backend)
    model, state = scene.model, scene.state
    n = state.x.shape[0]
    start = liquid_volumes(model, state, scene.containers)
    sim_wall = 0.0
    with Recorder(args.out) as rec, torch.no_grad():
        rec.write_state(state, scene.names, start)
        bar = tqdm(total=scene.steps, desc="pour", unit="step", disable=args.no_progress,
                   file=sys.stderr)
        for i in range(scene.steps):
            t0 = time.perf_counter()
            state = step(model, state, scene.poses[i])
            sim_wall += time.perf_counter() - t0
            if (i + 1) % args.every == 0 or i + 1 == scene.steps:
                rec.write_state(state, scene.names, liquid_volumes(model, state, scene.containers))
            bar.update(1)
        bar.close()
        frames = rec.frames
    end = liquid_volumes(model, state, scene.containers)
    total = time.perf_counter() - t_total

    rows = [
        ("backend", "fused" if model.use_fused(state.x) else "torch"),
        ("particles", f"{n}"),
        ("kernel radius h", f"{model.h * 100:.2f} cm"),
        ("steps", f"{scene.steps} (dt = 1/{round(1 / model.dt)} s, "
                  f"{scene.steps * model.dt:.2f} s simulated)"),
        ("wall time", f"{sim_wall:.1f} s stepping, {total:.1f} s total"),
        ("steps/s", f"{scene.steps / sim_wall:.1f}"),
        ("particle-steps/s", f"{n * scene.steps / sim_wall:,.0f}"),
    ]
    for name in start:
        rows.append((f"{name} (ml)", f"{start[name]:7.1f} at start → {end[name]:7.1f} at end"))
    rows += [("recording", f"{args.out} ({frames} frames)"),
             ("view it", f"liquidtwin-viewer --mcap {args.out}")]
    width = max(len(k) for k, _ in rows)
    print("liquidtwin demo: cup pours into a bowl")
    for k, v in rows:
        print(f"  {k:<{width}}  {v}")
    return 0


# ------------------------------------------------------------------ generate

def _configure_generate(p: argparse.ArgumentParser) -> None:
    p.add_argument("--list", action="store_true", help="print one line per scene and per effect, then exit")
    p.add_argument("--scene", metavar="NAME", help="scene to generate (see --list)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME[=VALUE][:KEY=X]",
                   help="hide an effect in the world (repeatable); VALUE in the effect's unit, drawn "
                        "from its realistic range when omitted; ':KEY=X' fixes a secondary parameter "
                        "the seed would draw (e.g. blockage=1.0:leg=left — the pipe's left leg, full); "
                        "'random' picks one effect or none")
    p.add_argument("--seed", type=int, default=0, metavar="N",
                   help="randomises scene, world, effect extras and sensor noise (default: %(default)s)")
    p.add_argument("--out", type=Path, metavar="REC.mcap",
                   help="recording to write; the truth goes to REC.truth.json (+ REC.truth.npz) beside it")
    p.add_argument("--quick", action="store_true", help="short, half-filled, 320x240 variant (tests, CI)")
    p.add_argument("--source", choices=("cup", "bottle", "mug"), help="pour scenes: the source container "
                   "(default: drawn from the seed)")
    p.add_argument("--target", choices=("bowl", "fruit_bowl", "dog_dish", "pan"),
                   help="pour scenes: the target container (default: drawn from the seed)")
    p.add_argument("--fill", type=float, metavar="FRACTION",
                   help="pour scenes: initial fill of the source, 0 (empty) to 1 (default: 0.3, 0.6 or 0.9 from the seed)")
    p.add_argument("--rgb", action="store_true", help="also write synthetic RGB frames")
    p.add_argument("--perfect-sensors", action="store_true",
                   help="no pose/mask noise and no dropped frames")
    p.add_argument("--threads", type=int, default=1, metavar="N", help="torch CPU threads (default: 1)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")


def run_generate(args: argparse.Namespace) -> int:
    """Generate a recording with optional hidden effects; print a summary."""
    from liquidtwin.generate import listing, parse_effect_extra
    if args.list:
        print("\n".join(listing()))
        return 0
    if not args.scene or args.out is None:
        print("liquidtwin generate: --scene and --out are required (or --list)", file=sys.stderr)
        return 2
    try:
        effects = [("random", None) if e.strip() == "random" else parse_effect_extra(e) for e in args.effect]
    except ValueError as exc:
        print(f"liquidtwin generate: {exc}", file=sys.stderr)
        return 2
    import torch
    torch.set_num_threads(max(1, args.threads))
    from liquidtwin.generate import generate
    t0 = time.perf_counter()
    try:
        g = generate(args.scene, args.out, effects=effects, seed=args.seed, quick=args.quick, rgb=args.rgb,
                     noise=not args.perfect_sensors, progress=not args.no_progress,
                     choices={"source": args.source, "target": args.target, "fraction": args.fill})
    except ValueError as exc:
        print(f"liquidtwin generate: {exc}", file=sys.stderr)
        return 2
    rows = [("recording", g.mcap), ("truth (never read by analysis)", g.truth), ("particles", g.particles),
            ("steps", g.steps), ("mask frames written", g.masks), ("mask frames dropped", g.dropped),
            ("wall time", f"{time.perf_counter() - t0:.1f} s")]
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"  {k:<{width}}  {v}")
    return 0


# ------------------------------------------------------------------ bench (module owned elsewhere)

def run_bench(argv: list[str]) -> int:
    from liquidtwin import bench  # lazy: keeps `liquidtwin demo` free of bench imports
    bench.main(argv)
    return 0


# ------------------------------------------------------------------ registry

#: Subcommands of ``liquidtwin``. Add new ones here.
COMMANDS: dict[str, Command] = {
    "demo": Command("the product demo: server + viewer + a robot client streaming a bundled pour "
                    "(--offline: simulate a pour to MCAP without the service)", _demo_run, _demo_configure),
    "generate": Command("write a synthetic recording (MCAP) of a thesis scene, optionally with hidden "
                        "effects; the truth goes to a sidecar", run_generate, _configure_generate),
    "bench": Command("speed and memory benchmarks of the SPNets step (JSON records)", run_bench,
                     passthrough=True),
}


from .service.cli import HELP as _SERVE_HELP, add_serve_parser, run_serve  # noqa: E402
COMMANDS["serve"] = Command(_SERVE_HELP, run_serve, add_serve_parser)
from .evaluate.cli import HELP as _EVAL_HELP, configure as _eval_configure, run as _eval_run  # noqa: E402
COMMANDS["evaluate"] = Command(_EVAL_HELP, _eval_run, _eval_configure)
from .discrepancy.cli import HELP as _DISC_HELP, configure as _disc_configure, run as _disc_run  # noqa: E402
COMMANDS["discrepancy"] = Command(_DISC_HELP, _disc_run, _disc_configure)
from .sysid.cli import HELP as _FIT_HELP, configure as _fit_configure, run as _fit_run  # noqa: E402
COMMANDS["fit"] = Command(_FIT_HELP, _fit_run, _fit_configure)


def build_parser() -> argparse.ArgumentParser:
    """The ``liquidtwin`` argument parser (pass-through commands parse their own options)."""
    parser = argparse.ArgumentParser(
        prog="liquidtwin",
        description="liquidtwin server: a live, differentiable SPNets twin of the liquid a "
                    "robot handles.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, cmd in COMMANDS.items():
        sp = sub.add_parser(name, help=cmd.help, description=cmd.help)
        if cmd.configure is not None:
            cmd.configure(sp)
        else:
            sp.add_argument("args", nargs=argparse.REMAINDER,
                            help=f"options of 'liquidtwin {name}' (see 'liquidtwin {name} --help')")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``liquidtwin`` console script; returns the exit code."""
    from .procs import WorkerDied
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] in COMMANDS and COMMANDS[argv[0]].passthrough:
            return int(COMMANDS[argv[0]].run(argv[1:]) or 0)
        args = build_parser().parse_args(argv)
        return int(COMMANDS[args.command].run(args) or 0)
    except WorkerDied as exc:           # any command's --jobs workers: say so, no traceback
        print(f"liquidtwin {argv[0]}: {exc}", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())


def _perception_configure(p: argparse.ArgumentParser) -> None:
    from .perception.cli import configure
    configure(p)


def _perception_run(args: argparse.Namespace) -> int:
    from .perception.cli import run
    return run(args)


COMMANDS["perception"] = Command("liquid detection from RGB: make the dataset, train a detector, run one on a "
                                 "recording", _perception_run, _perception_configure)
