"""``liquidtwin evaluate control``: MPC through SPNets on the thesis's control scenes (§8.3.3).

``--scene plate`` (default): tilt a plate about world x and z so the liquid resting on it
lands in one of 8 bowls; one run per bowl. Target: ≥ 99 % of the liquid in the target bowl
for 8/8 (thesis: 100 % for 7/8). The loss's lookahead, which sets how fast the liquid is
sent, follows the amount on the plate (``control.plate.lookahead_for``); ``--lookahead S``
fixes it.

``--scene catching``: slide a cup to catch the stream of a source that pours while it
moves (``control.catch``); one run per source motion (8). Target: ≥ 98 % caught in every
case (thesis: 96.5–98.9 %). Table: caught, spilled, the catcher's travel, s per control;
``catching.png``. ``--controller policy`` runs the learned policy (``control.policy``; the
shipped one or ``--policy FILE``) instead of the MPC and marks which motions it was trained
on.

``--scene pouring``: the thesis's 11 pours (75–275 g in 20 g steps from a full-size cup)
scaled to a quick scene: 60 ml in the cup, 11 asks from 10 to 30 ml in 2 ml steps
(``control.pour``, the predicted-drain switch). Quick scenes hold a fifth of the full scene's
liquid (``QUICK_FILL``), so the cup shrinks with it (``--cup-scale``, default
``QUICK_FILL``^⅓): 60 ml fill it as 300 ml fill the full-size cup (79 %), and the liquid
starts to flow at the tilt it would at full size. In the full-size cup (``--cup-scale 1``,
the benchmark before stop 28) 60 ml fill 16 %: nothing flows until ~85° of tilt, and then a
third of the liquid leaves in one surge. Table: asked, in the bowl, error, spilled,
s per update; ``pouring.png``. Target (issue 7): max error ≤ 5 g, mean ≤ 2 g, nothing
spilled (thesis 11 g / 5 g) — the table also gives the errors relative to each ask, which is
what carries over between cup sizes. ``--full`` runs the thesis's scale instead: the full scene
and the full-size cup with 300 ml in it (~2.9k particles), asks 75–275 ml in 20 ml steps
(slow: minutes of MPC per ask; ``--targets`` picks some).

Table: per target, the fraction of the liquid in the target bowl, in other bowls, spilled;
the maximum tilt; wall time per MPC update. Results: ``results.json`` + ``control.json``
(headline: targets with ≥ 99 % in the target bowl), ``plate.png`` (tilt over time and
where the liquid went).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..generate.catalog import QUICK_FILL
from .cli import save_results

HELP = ("control through SPNets, thesis §8.3.3: the plate scene (8 target bowls), catching (8 source "
        "motions; MPC or the learned policy) or pouring (11 asks)")
GOOD = 0.99
CATCH_GOOD = 0.98


def configure(p) -> None:
    p.add_argument("--out", type=Path, default=Path("eval-control"), metavar="DIR",
                   help="where the JSON and PNG results go (default: %(default)s)")
    p.add_argument("--scene", choices=("plate", "catching", "pouring"), default="plate",
                   help="(default: %(default)s)")
    p.add_argument("--quick", action="store_true",
                   help="the quick scene (a few hundred particles; pouring always runs the quick cup)")
    p.add_argument("--targets", default=None, metavar="K[,K]",
                   help="plate: target bowls; catching: source motions (default: all 8); pouring: ml to "
                        "pour (default: 10,12,…,30)")
    p.add_argument("--seconds", type=float, default=2.5,
                   help="plate: episode length, s (default: %(default)s; catching: the scene's)")
    p.add_argument("--horizon", type=int, default=10, help="MPC horizon, steps (default: %(default)s)")
    p.add_argument("--step-size", type=float, default=None,
                   help="MPC step on each control, rad/s or m/s (default: 0.5; catching 0.1 — at 0.5 the "
                        "catcher jerked between ±0.5 m/s and its catch sloshed out; plate: 0.5 × 0.25 s / the "
                        "lookahead, control.plate.step_for)")
    p.add_argument("--lookahead", type=float, default=None, metavar="S",
                   help="plate: the loss scores where each particle will be S seconds later at its velocity, "
                        "which sets how fast the liquid is sent (default: control.plate.lookahead_for the liquid "
                        "on the plate: 0.25 s, or its volume / 120 ml/s when longer — quick 0.25 s, full 1.42 s; "
                        "0.25 s for both before stop 52; the step follows it unless --step-size is given); "
                        "pouring: the same for the pull to the lip (default: control.pour.LOOKAHEAD_S); "
                        "offline runs only")
    p.add_argument("--controller", choices=("mpc", "policy"), default="mpc",
                   help="catching: the MPC or the learned policy (default: %(default)s)")
    p.add_argument("--policy", type=Path, default=None, metavar="FILE",
                   help="catching policy file (default: the shipped one; train with "
                        "python -m liquidtwin.control.train_policy)")
    p.add_argument("--approach-rate", type=float, default=None, metavar="RAD_S",
                   help="pouring: cap on the cup's forward tilt rate from 20 deg on, rad/s (default: none, "
                        "the full 2 rad/s; see control.pour)")
    p.add_argument("--full", action="store_true",
                   help="pouring: the thesis's scale — the full scene, the full-size cup with %g ml in it, asks "
                        "75,95,…,275 ml (default: the quick scene)" % POUR_FULL_FILL_ML)
    p.add_argument("--cup-scale", type=float, default=None, metavar="S",
                   help="pouring: the cup's lengths (not its 3 mm wall) × S, in (0, 1] (default: %.3f = "
                        "QUICK_FILL^(1/3), so 60 ml fill it as 300 ml fill the full-size cup; 1: the full-size cup; "
                        "--full: 1)" % POUR_CUP_SCALE)
    p.add_argument("--served", type=float, default=0.0, metavar="FPS",
                   help="plate / catching MPC: run the task as a session serves it — set on a session engine, "
                        "one Control per frame at FPS, a simulated robot moving the object to each Control's "
                        "pose (evaluate.served; the session's own horizon and steps: --horizon and --step-size do not "
                        "apply); default 0: the offline controller, one update per model step")
    p.add_argument("--seed", type=int, default=0,
                   help="scene draw (default: %(default)s; the plate scene's plate, bowls and liquid do not "
                        "depend on it, only its camera)")
    p.add_argument("--jobs", type=int, default=2, help="targets run in parallel (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")


def run_target(work) -> dict:
    import torch

    from ..control.plate import plate_scene, run_plate
    target, seed, quick, seconds, horizon, step_size, served, lookahead = work
    torch.set_num_threads(1)
    if served:
        from .served import serve_plate
        return serve_plate(target, seed, quick, seconds, served)
    setup, model, state = plate_scene(seed, quick)
    r = run_plate(setup, model, state, target, seconds=seconds, horizon=horizon, step_size=step_size,
                  lookahead_s=lookahead)
    return {"target": target, "particles": int(state.x.shape[0]), "iterations": model.iterations,
            "caught": r.caught, "in_bowls": r.in_bowls,
            "spilled": r.spilled, "on_plate": r.on_plate, "max_tilt_deg": float(np.abs(r.tilts_deg).max()),
            "tilts_deg": r.tilts_deg.tolist(),
            "losses": r.losses, "wall_s": r.wall_s, "update_s": r.update_s}


def run_motion(work) -> dict:
    import torch

    from ..control.catch import catching_setup, run_catch
    from ..generate.world import control_model
    from ..scenes.fill import fill_container
    motion, seed, quick, horizon, step_size, policy_file, served = work
    torch.set_num_threads(1)
    if served:
        from .served import serve_catch
        return serve_catch(motion, seed, quick, served, controller="mpc" if policy_file is None else "policy")
    policy = None
    if policy_file is not None:
        from ..control.policy import load_policy
        policy, _ = load_policy(None if policy_file == "shipped" else policy_file)
    setup = catching_setup(motion, quick, seed)
    model = control_model(setup)
    k = setup.index("source")
    state, _ = fill_container(model, torch.as_tensor(setup.poses_at(0.0)), k, setup.objects[k].model,
                              volume_ml=dict(setup.fills)["source"], settle_s=0.5)
    r = run_catch(setup, model, state, horizon=horizon, step_size=step_size, policy=policy)
    return {"motion": motion, "direction": setup.notes["direction"], "drift_m_s": setup.notes["drift_m_s"],
            "particles": int(state.x.shape[0]), "iterations": model.iterations, "caught": r.caught,
            "left_source": r.left_source,
            "spilled": r.spilled, "xs": r.xs.tolist(), "travel_m": float(r.xs.max() - r.xs.min()),
            "wall_s": r.wall_s, "update_s": r.update_s, "dt": float(setup.dt)}


POUR_FILL_ML = 60.0
#: The quick pour's cup: the full-size cup's lengths (not its wall) × QUICK_FILL^(1/3) (module doc).
POUR_CUP_SCALE = QUICK_FILL ** (1.0 / 3.0)
POUR_TARGETS_ML = tuple(float(v) for v in range(10, 31, 2))
#: ``--full``: the thesis's scale (the full scene, the full-size cup).
POUR_FULL_FILL_ML = 300.0
POUR_FULL_TARGETS_ML = tuple(float(v) for v in range(75, 276, 20))


def run_pour_target(work) -> dict:
    import torch

    from ..control.pour import run_pour
    from ..generate.catalog import build_setup
    from ..generate.world import control_model
    from ..scenes.fill import fill_container
    target, seed, horizon, step_size, approach_rate, cup_scale, full, fill_ml, lookahead = work
    torch.set_num_threads(1)
    setup = build_setup("pour_hold", np.random.default_rng(seed), quick=not full, source="cup", target="bowl",
                        fraction=0.9, source_scale=cup_scale)
    model = control_model(setup)
    k = setup.index("source")
    state, rep = fill_container(model, torch.as_tensor(setup.poses_at(0.0)), k, setup.objects[k].model,
                                volume_ml=fill_ml, settle_s=0.5)
    r = run_pour(setup, model, state, target, rep.settled_ml / state.x.shape[0], horizon=horizon,
                 step_size=step_size, approach_rate=approach_rate, lookahead_s=lookahead,
                 max_seconds=10.0 if full else 6.0)
    return {"target_ml": target, "particles": int(state.x.shape[0]), "iterations": model.iterations,
            "cup_ml": rep.settled_ml,
            "cup_capacity_ml": setup.objects[k].model.capacity_ml,
            "poured_ml": r.poured_ml, "error_ml": r.poured_ml - target, "spilled_ml": r.spilled_ml,
            "left_ml": r.left_ml, "switched_s": r.switched_s, "angles_deg": np.asarray(r.angles_deg).tolist(),
            "seconds": r.seconds, "update_s": r.update_s, "dt": float(model.dt)}


def run_pouring(args) -> int:
    from tqdm.auto import tqdm

    from ..procs import map_jobs
    fill_ml = POUR_FULL_FILL_ML if args.full else POUR_FILL_ML
    cup_scale = (1.0 if args.full else POUR_CUP_SCALE) if args.cup_scale is None else args.cup_scale
    if args.targets is None:
        targets = list(POUR_FULL_TARGETS_ML if args.full else POUR_TARGETS_ML)
    else:
        try:
            targets = [float(t) for t in args.targets.split(",") if t.strip()]
        except ValueError:
            raise SystemExit(f"--targets takes ml to pour, got {args.targets!r}") from None
        if not targets or any(not 0 < t < fill_ml for t in targets):
            raise SystemExit(f"--targets takes ml to pour, each in (0, {fill_ml:g}), got {args.targets!r}")
    from ..control import ControlError
    from ..control.pour import LOOKAHEAD_S as POUR_LOOKAHEAD_S
    from ..control.pour import check_approach_rate
    try:
        check_approach_rate(args.approach_rate)
    except ControlError as e:
        raise SystemExit(f"--approach-rate: {e}") from None
    if not 0.0 < cup_scale <= 1.0:
        raise SystemExit(f"--cup-scale must be in (0, 1], got {cup_scale}")
    lookahead = POUR_LOOKAHEAD_S if args.lookahead is None else float(args.lookahead)
    work = [(t, args.seed, args.horizon, args.step_size, args.approach_rate, cup_scale, args.full, fill_ml, lookahead)
            for t in targets]
    t0 = time.perf_counter()
    results = list(tqdm(map_jobs(run_pour_target, work, args.jobs), total=len(work), desc="pouring", unit="pour",
                        disable=args.no_progress))
    err = np.array([r["error_ml"] for r in results])
    spilled = np.array([r["spilled_ml"] for r in results])
    rel = err / np.array(targets)
    doc = {"kind": "control", "scene": "pouring", "quick": not args.full, "seed": args.seed, "fill_ml": fill_ml,
           "cup_scale": cup_scale, "cup_capacity_ml": results[0]["cup_capacity_ml"] if results else None,
           "horizon": args.horizon, "step_size": args.step_size, "approach_rate": args.approach_rate,
           "lookahead_s": lookahead, "wall_s": time.perf_counter() - t0,
           "max_abs_error_ml": float(np.abs(err).max()), "mean_abs_error_ml": float(np.abs(err).mean()),
           "mean_error_ml": float(err.mean()), "max_spilled_ml": float(spilled.max()),
           "max_abs_error_rel": float(np.abs(rel).max()), "mean_abs_error_rel": float(np.abs(rel).mean()),
           "results": results,
           "headline": {"name": "pouring max |error|", "value": float(np.abs(err).max()), "unit": "ml"}}
    out = save_results(args.out, doc)
    print(f"{'asked':>7}{'poured':>9}{'error':>9}{'rel':>8}{'spilled':>9}{'switch':>8}{'s/update':>10}")
    for r in results:
        print(f"{r['target_ml']:>5.0f}ml{r['poured_ml']:>7.2f}ml{r['error_ml']:>+7.2f}ml"
              f"{100 * r['error_ml'] / r['target_ml']:>+7.1f}%{r['spilled_ml']:>7.2f}ml"
              f"{(r['switched_s'] or float('nan')):>7.2f}s{r['update_s']:>10.2f}")
    print(f"\n|error| max {np.abs(err).max():.2f} ml, mean {np.abs(err).mean():.2f} ml (mean signed {err.mean():+.2f}); "
          f"relative max {100 * np.abs(rel).max():.1f} %, mean {100 * np.abs(rel).mean():.1f} %; spilled up to "
          f"{spilled.max():.2f} ml. Thesis (75–275 g, full-size cup): max 11 g, mean 5 g, none spilled. "
          f"{doc['wall_s']:.0f} s. Results in {out}")
    _plot_pouring(out / "pouring.png", results, "the full-size cup" if cup_scale == 1.0 else f"the cup × {cup_scale:.3g}",
                  fill_ml)
    return 0


def _targets(args) -> list[int]:
    what = "bowl numbers" if args.scene == "plate" else "source motions"
    if args.targets is None:
        return list(range(8))
    try:
        targets = [int(t) for t in args.targets.split(",") if t.strip()]
    except ValueError:
        raise SystemExit(f"--targets takes {what} 0-7, got {args.targets!r}") from None
    if not targets or any(not 0 <= t < 8 for t in targets):
        raise SystemExit(f"--targets takes {what} 0-7, got {args.targets!r}")
    return targets


def run_catching(args, targets) -> int:
    from tqdm.auto import tqdm

    from ..procs import map_jobs
    trained, policy_file = [], None
    if args.controller == "policy":
        from ..control.policy import PolicyError, load_policy
        try:
            _, meta = load_policy(args.policy)           # fails here, clearly, before any work
        except PolicyError as e:
            raise SystemExit(str(e)) from None
        trained, policy_file = list(meta.get("motions", [])), str(args.policy or "shipped")
        if meta.get("quick", True) != args.quick:
            print(f"note: the policy was trained on the {'quick' if meta.get('quick', True) else 'full'} scene")
    work = [(m, args.seed, args.quick, args.horizon, args.step_size, policy_file, args.served) for m in targets]
    t0 = time.perf_counter()
    results = list(tqdm(map_jobs(run_motion, work, args.jobs), total=len(work), desc="catching", unit="motion",
                        disable=args.no_progress))
    for r in results:
        r["trained_on"] = r["motion"] in trained
    good = sum(r["caught"] >= CATCH_GOOD for r in results)
    doc = {"kind": "control", "scene": "catching", "controller": args.controller, "policy": policy_file,
           "served_fps": args.served,
           "trained_motions": trained, "quick": args.quick, "seed": args.seed, "horizon": args.horizon,
           "step_size": args.step_size, "wall_s": time.perf_counter() - t0, "results": results,
           "headline": {"name": "catching motions with >= 98 % caught", "value": good, "unit": f"of {len(results)}"}}
    out = save_results(args.out, doc)
    print(f"{'motion':>6}{'pours to':>9}{'lip drift':>11}{'caught':>8}{'spilled':>9}{'travel':>8}{'s/control':>10}"
          + ("   policy" if trained else ""))
    for r in results:
        print(f"{r['motion']:>6}{('-x' if r['direction'] < 0 else '+x'):>9}{r['drift_m_s']:>9.2f}m/s"
              f"{100 * r['caught']:>7.1f}%{100 * r['spilled']:>8.1f}%{100 * r['travel_m']:>6.1f}cm{r['update_s']:>10.3f}"
              + (("   trained" if r["trained_on"] else "   unseen") if trained else ""))
    print(f"\n{args.controller}{f' served at {args.served:g} fps' if args.served else ''}: {good}/{len(results)} motions with ≥ 98 % caught (thesis: 96.5–98.9 %); "
          f"{doc['wall_s']:.0f} s. Results in {out}")
    _plot_catching(out / "catching.png", results, args.controller)
    return 0


def run(args) -> int:
    from tqdm.auto import tqdm

    from ..procs import map_jobs
    if args.step_size is None and args.scene != "plate":      # the plate's follows its lookahead
        args.step_size = 0.1 if args.scene == "catching" else 0.5
    if not args.seconds > 0 or args.horizon < 1 or not (args.step_size is None or args.step_size > 0):
        raise SystemExit("--seconds and --step-size must be > 0, --horizon >= 1")
    if args.served:
        if not (np.isfinite(args.served) and args.served > 0):
            raise SystemExit(f"--served takes frames per second > 0, got {args.served}")
        if args.scene == "pouring":
            raise SystemExit("--served runs the plate and catching tasks; a served pour: python bench/session_pour.py")
        if args.controller == "policy" and (args.scene != "catching" or args.policy is not None):
            raise SystemExit("--served --controller policy runs the shipped catching policy (a session's catch "
                             "task with controller 'policy'); --policy FILE is for offline runs")
    if args.lookahead is not None:
        if args.scene == "catching" or args.served:
            raise SystemExit("--lookahead sets the offline plate and pouring MPC's loss (a served task uses the "
                             "session's)")
        if not (np.isfinite(args.lookahead) and args.lookahead >= 0):
            raise SystemExit(f"--lookahead takes seconds >= 0, got {args.lookahead}")
    if args.scene == "pouring":
        return run_pouring(args)
    targets = _targets(args)
    if args.scene == "catching":
        return run_catching(args, targets)
    lookahead = None if args.lookahead is None else float(args.lookahead)
    work = [(t, args.seed, args.quick, args.seconds, args.horizon, args.step_size, args.served, lookahead)
            for t in targets]
    t0 = time.perf_counter()
    results = []
    for r in tqdm(map_jobs(run_target, work, args.jobs), total=len(work), desc="plate", unit="target",
                  disable=args.no_progress):
        results.append(r)
    good = sum(r["caught"] >= GOOD for r in results)
    doc = {"kind": "control", "scene": "plate_tilt", "served_fps": args.served, "quick": args.quick, "seed": args.seed,
           "seconds": args.seconds, "lookahead_s": None if args.served else lookahead,     # None: the default rule
           "horizon": args.horizon, "step_size": args.step_size, "wall_s": time.perf_counter() - t0,
           "results": results,
           "headline": {"name": "plate targets with >= 99 % in the target bowl", "value": good,
                        "unit": f"of {len(results)}"}}
    out = save_results(args.out, doc)
    print(f"{'target':>6}{'in target':>11}{'other bowls':>13}{'spilled':>9}{'max tilt':>10}{'s/update':>10}")
    for r in results:
        other = sum(r["in_bowls"]) - r["caught"]
        print(f"{r['target']:>6}{100 * r['caught']:>10.1f}%{100 * other:>12.1f}%{100 * r['spilled']:>8.1f}%"
              f"{r['max_tilt_deg']:>9.1f}°{r['update_s']:>10.2f}")
    mean = 100 * float(np.mean([r["caught"] for r in results]))
    print(f"\n{f'served at {args.served:g} fps: ' if args.served else ''}{good}/{len(results)} targets with ≥ 99 % in the target bowl (thesis: 7/8 at 100 %), mean {mean:.1f} %; "
          f"{doc['wall_s']:.0f} s. Results in {out}")
    _plot(out / "plate.png", results, args.seconds)
    return 0


def _figure(path: Path, results: list[dict], key: str, good: float, what: str, title: str, draw) -> None:
    """Left: ``draw(axes)`` (the controls over time); right: the liquid per run, caught on
    spilled, with the target line at ``good``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    draw(a)
    a.set_xlabel("time (s)")
    a.legend(fontsize=7, ncol=2)
    idx = np.arange(len(results))
    b.bar(idx, [100 * r["caught"] for r in results], label="caught")
    b.bar(idx, [100 * r["spilled"] for r in results], bottom=[100 * r["caught"] for r in results], label="spilled")
    b.set_xticks(idx, [str(r[key]) for r in results])
    b.set_xlabel(what)
    b.set_ylabel("% of the liquid")
    b.axhline(100 * good, color="k", lw=0.6, ls=":")
    b.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot(path: Path, results: list[dict], seconds: float) -> None:
    def draw(a):
        for r in results:
            tl = np.asarray(r["tilts_deg"])
            t = np.linspace(0, seconds, len(tl))
            a.plot(t, tl[:, 0], label=f"bowl {r['target']} x")
            a.plot(t, tl[:, 1], ls="--")
        a.set_ylabel("tilt (deg): about x solid, about z dashed")
    _figure(path, results, "target", GOOD, "target bowl", "Plate scene: MPC through SPNets", draw)


def _plot_catching(path: Path, results: list[dict], controller: str = "mpc") -> None:
    def draw(a):
        for r in results:
            xs = np.asarray(r["xs"])
            a.plot(np.arange(1, len(xs) + 1) * r["dt"], 100 * xs, label=f"motion {r['motion']}")
        a.set_ylabel("catcher x (cm)")
    title = "Catching: " + ("MPC through SPNets" if controller == "mpc" else "policy learned through SPNets")
    _figure(path, results, "motion", CATCH_GOOD, "source motion", title, draw)


def _plot_pouring(path: Path, results: list[dict], cup: str, fill_ml: float) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    for r in results:
        ang = np.asarray(r["angles_deg"])
        a.plot(np.arange(1, len(ang) + 1) * r["dt"], ang, label=f"{r['target_ml']:g} ml")
    a.set_xlabel("time (s)")
    a.set_ylabel("cup tilt (deg)")
    a.legend(fontsize=7, ncol=2)
    asked = np.array([r["target_ml"] for r in results])
    b.plot(asked, asked, "k:", lw=0.8, label="asked")
    b.plot(asked, [r["poured_ml"] for r in results], "o-", label="in the bowl")
    b.bar(asked, [r["spilled_ml"] for r in results], width=0.8, color="tab:red", alpha=0.6, label="spilled")
    b.set_xlabel("asked (ml)")
    b.set_ylabel("ml")
    b.legend(fontsize=8)
    fig.suptitle(f"Pouring: MPC through SPNets, {cup} ({fill_ml:g} ml)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
