"""How much a session's twin pours against the robot world it tracks, by PBF solver iterations.

The robot world of ``examples/04_robot_world.py`` (the generator's physics: jittered fluid,
the model's iterations + 2, the hidden effect) and open-loop session engines built from the
spec the robot states, at several solver iterations, all turn the cup on one script: up at
``--rate`` about the session's pour axis until ``--back`` s (at most ``--max-angle``), back
upright at the same rate, then still until ``--seconds``. Every frame (``--fps``) each
reports what has left the cup and what the target holds (the world: its own count, the
truth; the engines: the session's count, the twin). No camera: the twins run open loop, so
this measures the model, not the tracker.

    OMP_NUM_THREADS=1 python bench/pour_iterations.py --seeds 1 2 3 4 --iterations 3 4 6 8 12 \\
        --effect drag --json bench/results/pour_iterations.json

Why: the pour MPC decides when to turn back from its own model's drain prediction, before the
camera has seen where the stream lands, so a model that pours more than the world turns back
early. SPNets applies cohesion once per solver iteration, so the iteration count is part of
the liquid: ``--cohesion default`` shows the pour stop as iterations grow, ``zero`` (no
cohesion) converges, and ``per-step`` (``simulation.reference_iterations``: every count
applies the cohesion of ``--reference`` iterations) keeps the liquid while the solve
improves. Until stop 41 the generator's world ran its extra iterations with SPNets' cohesion,
a stickier liquid than its λ_c said (results ``bench/results/pour_iterations_*``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb
from tqdm.auto import tqdm

from liquidtwin.control.tilt import pour_axis, turn_pose
from liquidtwin.generate.robot import RobotWorld
from liquidtwin.session import SessionEngine


def script(a) -> list:
    """Tilt (rad) at the end of every frame: up at a.rate until a.back s, back at a.rate, still."""
    dt, angle, out = 1.0 / a.fps, 0.0, []
    for i in range(int(round(a.seconds * a.fps))):
        t = (i + 1) * dt
        angle = min(angle + a.rate * dt, a.max_angle) if t <= a.back + 1e-9 else max(angle - a.rate * dt, 0.0)
        out.append(angle)
    return out


def run_world(seed: int, a, tilts) -> dict:
    world = RobotWorld("pour_dump", seed=seed, quick=True, effects=a.effect, noise=False,
                       choices={"source": "cup", "target": "pan"})
    k, before = world.setup.index("source"), world.held_ml()
    target = world.poses[world.setup.index("target")][:3]
    axis = pour_axis(world.setup.objects[k].model.mesh.vertices, world.poses[k], target)
    pose0, left, landed = world.poses[k].copy(), [], []
    for angle in tilts:
        pose = turn_pose(pose0, axis.pivot_world(pose0), axis.axis, angle)
        world.move({"source": pose}, 1.0 / a.fps)
        now = world.held_ml()
        left.append(before["source"] - now["source"])
        landed.append(now["target"] - before["target"])
    return {"who": "world", "iterations": int(world.world.model.iterations), "left_ml": left, "landed_ml": landed,
            "effects": [e.as_dict() for e in world.effects], "spec": world.spec()}


def run_twin(spec, iterations: int, a, tilts) -> dict:
    spec = type(spec).FromString(spec.SerializeToString())
    spec.simulation.iterations = iterations
    if a.cohesion == "per-step":
        spec.simulation.reference_iterations = a.reference
    fluid = pb.FluidParameters(lambda_c=0.0) if a.cohesion == "zero" else pb.FluidParameters()
    eng = SessionEngine.create(pb.SessionSpec(scene=spec, tracking=pb.OPEN_LOOP, fluid=fluid))
    eng.advance(0.0, {})
    k, t_ = eng.object_names.index("source"), eng.object_names.index("target")
    pose0 = np.asarray(spec.objects[k].initial_pose, float)
    axis = pour_axis(eng._scene.objects[k].mesh.vertices, pose0, np.asarray(spec.objects[t_].initial_pose, float)[:3])
    before, left, landed = eng.volumes(), [], []
    for i, angle in enumerate(tilts):
        eng.advance((i + 1) / a.fps, {"source": turn_pose(pose0, axis.pivot_world(pose0), axis.axis, angle)})
        now = eng.volumes()
        left.append(before["source"] - now["source"])
        landed.append(now["target"] - before["target"])
    return {"who": "twin", "iterations": iterations, "lambda_c": float(eng._model.params.lambda_c),
            "reference_iterations": eng._model.reference_iterations,
            "left_ml": left, "landed_ml": landed, "particles": eng.n_particles}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, nargs="+", default=[1], help="robot-world seeds (default: %(default)s)")
    p.add_argument("--iterations", type=int, nargs="+", default=[4, 6, 8], help="twin solver iterations")
    p.add_argument("--effect", action="append", default=[], type=lambda s: (s, None),
                   help="hidden effect in the world, value drawn from the seed (repeatable; default: none)")
    p.add_argument("--rate", type=float, default=1.5, help="tilt rate, rad/s (default: %(default)s)")
    p.add_argument("--back", type=float, default=1.0, help="turn back at, s (default: %(default)s)")
    p.add_argument("--max-angle", type=float, default=2.0, help="tilt limit, rad (default: %(default)s)")
    p.add_argument("--seconds", type=float, default=3.0, help="length, s (default: %(default)s)")
    p.add_argument("--fps", type=float, default=30.0, help="frames per s (default: %(default)s)")
    p.add_argument("--cohesion", default="default", choices=("default", "per-step", "zero"),
                   help="twins' cohesion: default (SPNets: λ_c in full every iteration); per-step "
                        "(simulation.reference_iterations = --reference: every count applies what "
                        "--reference iterations do); zero (λ_c = 0) (default: %(default)s)")
    p.add_argument("--reference", type=int, default=4, help="reference_iterations of per-step (default: %(default)s)")
    p.add_argument("--json", help="write every series here")
    a = p.parse_args(argv)
    if min(a.iterations) < 1 or a.rate <= 0 or a.fps <= 0 or a.seconds <= a.back:
        p.error("iterations >= 1, rate and fps > 0, seconds > back")
    torch.set_num_threads(1)
    tilts = script(a)
    rows, t0 = [], time.perf_counter()
    for seed in a.seeds:
        w = run_world(seed, a, tilts)
        spec = w.pop("spec")
        rows.append({"seed": seed, **w})
        for it in tqdm(a.iterations, desc=f"seed {seed}", unit="twin", leave=False):
            rows.append({"seed": seed, "cohesion": a.cohesion, **run_twin(spec, it, a, tilts)})
    print(f"scripted tilt: {a.rate:g} rad/s up to {math.degrees(max(tilts)):.0f}° until {a.back:g} s, back; "
          f"ml at {a.seconds:g} s ({time.perf_counter() - t0:.0f} s)")
    print(f"{'seed':>4} {'who':>5} {'iter':>4} {'λ_c':>6} {'coh. it':>7} {'left cup':>9} {'landed':>7}")
    for r in rows:
        lc = f"{r['lambda_c']:6.3f} {r['reference_iterations'] or '-':>7}" if r["who"] == "twin" else f"{'':>14}"
        print(f"{r['seed']:>4} {r['who']:>5} {r['iterations']:>4} {lc} "
              f"{r['left_ml'][-1]:9.2f} {r['landed_ml'][-1]:7.2f}")
    out = {"argv": sys.argv[1:], "tilts_rad": tilts, "rows": rows}
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
