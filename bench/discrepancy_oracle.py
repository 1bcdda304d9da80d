"""Could any candidate have been named? The *perfect model* of a generated recording against the
analysis's calibrated base, each averaged over jittered realisations.

    OMP_NUM_THREADS=1 .venv/bin/python bench/discrepancy_oracle.py DIR/*.mcap [--realisations 4] \
        [--results RESULTS.json] [--lambda-c 0.075,0.09,0.1,0.11,0.125] \
        [--out bench/results/discrepancy_oracle.json]

For each recording (a blind benchmark's, ``liquidtwin evaluate discrepancy --data DIR``) it runs
the analysis's own preparation and calibration (blind, as ``liquidtwin discrepancy`` does), then
reads the truth sidecar (a diagnostic of the benchmark, never part of the analysis) and rolls
out, from the same settled fill with ``--realisations`` initial-velocity jitters (the null's
1 mm/s, seeds 1000, 1001, …) each:

- ``base``: the calibrated base (no effect), what every candidate's gain is measured from;
- ``effect``: the planted effect at its true value on the calibrated base: the best a fitted
  candidate of the right kind can do with the base's λ;
- ``world``: the world's own λ_v and λ_c (calibration's error removed), no effect;
- ``perfect``: the world's λ and the planted effect: the model that generated the recording,
  up to its settled fill, pose and mask noise.

Each is scored with the analysis's per-frame loss on the held-out frames, averaged over the
realisations, and compared with ``base`` by the analysis's interval (block bootstrap,
stratified); and by the energy score of its realisations (``energy``: that mean less half the
mean loss between two of them, as ``analysis.ensemble_losses`` scores ``Options.score``
"energy"). A gain whose interval reaches zero for ``perfect`` says the recording does not
show the effect through this loss: no candidate can be named on it by a held-out gain. The
camera offset's ``effect`` is not built (the world's offset also shifts the camera, which the
candidate does not model); its ``perfect`` draws the world's λ with the camera the world filmed
with (the sidecar's true pose). With ``--results`` (the benchmark's ``results.json``) each row also
shows what the analysis named. ``--lambda-c`` adds, per value c, ``perfect λ_c=c``: the perfect
model with the world's λ_c replaced by c (how sharply the recording's loss depends on the
cohesion the model is given, e.g. whether a viscosity could be fitted at a calibrated λ_c; a
planted cohesion sets λ_c itself, so there these rows equal ``perfect``).
Writes JSON; prints a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import subprocess
import time
from pathlib import Path

import numpy as np


def _planted(eff: dict | None, base: dict):
    """The Extension of the planted effect on ``base`` (λ dict); None where none is built."""
    from liquidtwin.discrepancy.model import Extension
    if eff is None:
        return Extension("none", {}, base)
    n, v, x = eff["name"], float(eff["value"]), eff.get("extra") or {}
    if n == "viscosity":
        return Extension("none", {}, {**base, "lambda_v": v})
    if n == "cohesion":
        return Extension("none", {}, {**base, "lambda_c": v})
    az = math.radians(float(x.get("azimuth_deg", 0.0)))
    params = {"drag": {"c": v}, "wall_adhesion": {"k": v}, "fill_error": {"value": v}, "time_offset": {"s": v},
              "blockage": {"fraction": v},
              "leak": {"radius": v, "height_fraction": x.get("height_fraction"), "azimuth_deg": x.get("azimuth_deg")},
              "wind": {"ax": v * math.cos(az), "az": v * math.sin(az)}}.get(n)
    return None if params is None else Extension(n, {k: float(q) for k, q in params.items()}, base)


def oracle(rec: Path, realisations: int, lambda_c: tuple = ()) -> dict:
    import torch

    from liquidtwin.discrepancy.analysis import (NULL_JITTER, Options, _held, _held_strata, calibrate, interval,
                                                 prepare)
    from liquidtwin.discrepancy.model import Extension
    from liquidtwin.discrepancy.residuals import cell_metrics, coarse
    t0 = time.perf_counter()
    eps, sims, ev, frames, data, split, pool = prepare([rec], Options(jobs=1))
    base, _ = calibrate(sims, ev, pool, data)
    truth = json.loads(Path(str(rec)[: -len(".mcap")] + ".truth.json").read_text())   # after calibrating
    world = {k: float(truth["world"]["params"][k]) for k in ("lambda_v", "lambda_c")}
    eff = truth["effect"]
    sim, f = sims[0], frames[0]
    _, blocks = _held(ev.losses(base, data.cells), data)
    strata = _held_strata(data)
    rng = np.random.default_rng(0)

    true_cam = None
    if eff is not None and eff["name"] == "camera_offset":     # the camera the world filmed with
        pose = truth["cameras"][eps[0].camera.name]["true_pose"]
        true_cam = dataclasses.replace(eps[0], camera=eps[0].camera.with_pose(torch.tensor(pose, dtype=torch.float64)))

    def held(ext, episode=None) -> np.ndarray:
        """(realisations, held-out frames) losses of ``ext`` (drawn with ``episode``'s camera)."""
        stated, sim.ep = sim.ep, episode or sim.ep
        try:
            return _held_losses(ext)
        finally:
            sim.ep = stated

    def _held_losses(ext) -> tuple[np.ndarray, np.ndarray]:
        """(realisations, held-out frames) losses, and (held-out frames,) energy scores."""
        out, drawn = [], []
        for k in range(realisations):
            x0, v0 = sim.initial(ext.fill_scale)
            gen = torch.Generator().manual_seed(1000 + k)
            traj = sim.rollout(ext, initial=(x0, v0 + NULL_JITTER * torch.randn(v0.shape, generator=gen)))
            drawn.append(coarse(sim.render(traj, f, ext=ext)))
            out.append(_held([cell_metrics(drawn[-1], data.cells[0])["loss"]], data)[0])
        out = np.stack(out)
        spread = np.mean([cell_metrics(drawn[a], drawn[b])["loss"] for a, b in
                          itertools.combinations(range(realisations), 2)], axis=0)
        return out, out.mean(0) - 0.5 * _held([spread], data)[0]

    models = {"base": Extension("none", {}, base.base), "effect": _planted(eff, base.base),
              "world": Extension("none", {}, world), "perfect": _planted(eff, world)}
    for c in lambda_c:                       # the perfect model at other cohesions
        models[f"perfect λ_c={c:g}"] = _planted(eff, {**world, "lambda_c": float(c)})
    losses, energy, rows = {}, {}, {}
    for name, ext in models.items():
        if ext is None and not (name == "perfect" and true_cam is not None):
            rows[name] = None
            continue
        losses[name], energy[name] = held(ext) if ext is not None else held(models["world"], true_cam)
        gain = losses["base"].mean(0) - losses[name].mean(0)
        egain = energy["base"] - energy[name]
        rows[name] = {"heldout_loss": [float(x) for x in losses[name].mean(1)],
                      "gain": float(gain.mean()), "ci95": interval(gain, blocks, rng, 2000, strata),
                      "energy": {"gain": float(egain.mean()), "ci95": interval(egain, blocks, rng, 2000, strata)}}
    return {"recording": rec.name, "planted": eff, "calibrated": base.base, "world": world,
            "realisations": realisations, "models": rows, "wall_s": round(time.perf_counter() - t0, 1)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("recordings", nargs="+", type=Path, help="generated recordings (each with its .truth.json)")
    p.add_argument("--realisations", type=int, default=4, help="jittered rollouts per model (default 4)")
    p.add_argument("--results", type=Path, help="the benchmark's results.json: adds what the analysis named")
    p.add_argument("--lambda-c", default="", metavar="C,C,…",
                   help="also draw the perfect model with these λ_c instead of the world's (comma-separated)")
    p.add_argument("--out", type=Path, default=Path("bench/results/discrepancy_oracle.json"))
    args = p.parse_args()
    try:
        lambda_c = tuple(float(c) for c in args.lambda_c.split(",") if c.strip())
    except ValueError:
        p.error(f"--lambda-c takes comma-separated numbers, got {args.lambda_c!r}")
    if any(not c > 0 for c in lambda_c):
        p.error("--lambda-c values must be > 0")
    if args.realisations < 2:
        p.error("--realisations must be at least 2")
    named = {}
    if args.results:
        named = {r["case"]["name"]: r["named"] for r in json.loads(args.results.read_text())["rows"]}
    rows = []
    for i, rec in enumerate(args.recordings):
        print(f"[{i + 1}/{len(args.recordings)}] {rec.name}", flush=True)
        r = oracle(rec, args.realisations, lambda_c)
        r["named"] = named.get(rec.stem)
        rows.append(r)
        eff = r["planted"]
        cells = "  ".join(f"{k} —" if m is None else
                          f"{k} {m['gain']:+.3f} [{m['ci95'][0]:+.3f}, {m['ci95'][1]:+.3f}] (energy "
                          f"{m['energy']['gain']:+.3f} [{m['energy']['ci95'][0]:+.3f}, {m['energy']['ci95'][1]:+.3f}])"
                          for k, m in r["models"].items() if k != "base")
        print(f"  planted {eff['name'] if eff else 'none'} {eff['value'] if eff else ''}, named {r['named']}: {cells}",
              flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"commit": commit, "lambda_c": list(lambda_c), "rows": rows}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
