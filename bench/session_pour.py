"""A session's pour task closed loop, PD baseline vs MPC: a simulated robot turns the source at
each Control's rate about the Control's axis, the session engine tracks the liquid from those
poses (open loop: the world is the session's own model), and the task stops the pour.

    python bench/session_pour.py --controllers pid,mpc --ml 8 --fps 30

Scene: the bundled golden dump pour's spec (cup of 23 ml over a pan, 322 particles). Reports
what reached the target, the wall time per control update (the MPC's gradient step plus its
drain predictions) until the switch, and appends one JSON record per controller to bench/history.jsonl
(``--no-history`` to skip).
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb
from tqdm.auto import tqdm

from _record import emit
from liquidtwin.control.tilt import tilt_from_upright, turn_pose
from liquidtwin.recordings import read_recording
from liquidtwin.session import SessionEngine

SPEC = Path(__file__).resolve().parents[1] / "tests" / "server" / "data" / "golden_pour_dump.mcap"


def pour(spec, controller: str, ml: float, fps: float, max_angle: float, max_rate: float, seconds: float) -> dict:
    eng = SessionEngine.create(pb.SessionSpec(scene=spec, tracking=pb.OPEN_LOOP))
    eng.advance(0.0, {})
    held0 = eng.volumes()["source"]
    eng.set_task(pb.Task(pour=pb.Task.PourToVolume(source="source", target="target", volume_ml=ml,
                                                   max_angle_rad=max_angle, max_rate_rad_s=max_rate),
                         controller=controller))
    k = eng.object_names.index("source")
    pose = np.asarray(spec.objects[k].initial_pose, float)
    dt, t, done_at, top, update_s = 1.0 / fps, 0.0, None, 0.0, []
    for _ in tqdm(range(int(seconds * fps)), desc=f"{controller} {ml:g} ml", unit="frame", leave=False):
        t0 = time.perf_counter()
        c = eng.control()
        if done_at is None:                       # updates while pouring (then: a fixed return)
            update_s.append(time.perf_counter() - t0)
        if c.done and done_at is None:
            done_at = t
        tilt = tilt_from_upright(pose)
        if done_at is not None and t > done_at + 1.5 and tilt < 1e-6:
            break
        turn = min(max(tilt + c.tilt_rate_rad_s * dt, 0.0), max_angle) - tilt
        pose = turn_pose(pose, c.axis_point_m, c.axis_direction, turn)
        top = max(top, tilt_from_upright(pose))
        t += dt
        eng.advance(t, {"source": pose})
    c, vols = eng.control(), eng.volumes()
    return {"what": "session_pour", "controller": controller, "particles": eng.n_particles, "fps": fps,
            "max_rate_rad_s": max_rate, "target_ml": ml, "poured_ml": c.achieved_ml,
            "spilled_ml": held0 - vols["source"] - vols["target"], "switched_s": done_at,
            "max_angle_deg": math.degrees(top), "pouring_update_s_median": float(np.median(update_s)),
            "pouring_update_s_max": float(np.max(update_s))}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--controllers", default="pid,mpc", help="comma-separated (default: %(default)s)")
    p.add_argument("--ml", type=float, default=8.0, help="ml to pour (default: %(default)s)")
    p.add_argument("--fps", type=float, default=30.0, help="frames (control updates) per s (default: %(default)s)")
    p.add_argument("--max-angle", type=float, default=2.0, help="tilt limit, rad (default: %(default)s)")
    p.add_argument("--max-rate", type=float, default=1.5, help="rate limit, rad/s (default: %(default)s)")
    p.add_argument("--seconds", type=float, default=6.0, help="longest run, s (default: %(default)s)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--no-history", action="store_true")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    spec = read_recording(SPEC, images=False).spec
    for controller in a.controllers.split(","):
        emit(pour(spec, controller, a.ml, a.fps, a.max_angle, a.max_rate, a.seconds), not a.no_history)


if __name__ == "__main__":
    main()
