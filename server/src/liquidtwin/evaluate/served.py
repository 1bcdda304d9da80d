"""The plate and catching tasks *served*: set on a session engine (the server's, with the
scene's spec), one Control per frame at ``fps``, and a simulated robot that puts the
controlled object where each Control's ``pose`` says while the rest of the scene follows its
script. The world is the session's own model (open loop), so what differs from
``evaluate control``'s offline runs is only what serving changes: one update per frame instead
of per model step, the session's state and limits, and (catching) a source whose motion the
controller does not know but extrapolates from the frames.

Used by ``liquidtwin evaluate control --scene plate|catching --served FPS``; the results have
the offline runs' keys.
"""

from __future__ import annotations

import time

import numpy as np


def _engine(setup):
    """(spec, engine): a session of ``setup``'s spec, solved with the control tasks'
    iterations, correction cap and wall cut (``generate.world.control_model``; the offline
    runs' model) for the same liquid."""
    from liquidtwin_proto import liquidtwin_pb2 as pb

    from ..generate.generator import scene_spec
    from ..generate.world import CONTROL_MAX_CORRECTION_SPACINGS, impact_iterations
    from ..scenes.spec import solve_with
    from ..session import SessionEngine
    spec = solve_with(scene_spec(setup), impact_iterations(setup))
    spec.simulation.max_correction_spacings = CONTROL_MAX_CORRECTION_SPACINGS
    spec.simulation.cut_wall_pairs = True
    eng = SessionEngine.create(pb.SessionSpec(scene=spec, tracking=pb.OPEN_LOOP))
    eng.advance(0.0, {})
    return spec, eng


def _drive(eng, setup, name: str, task, fps: float, seconds: float, script: tuple = ()):
    """Run ``task`` for ``seconds`` at ``fps``: returns ((frames, 7) poses of object ``name``
    after each frame, s per Control). ``script``: objects that follow the scene's motion."""
    eng.set_task(task)
    ks = {n: setup.index(n) for n in script}
    t, poses, update_s = 0.0, [], []
    for _ in range(int(round(seconds * fps))):
        t0 = time.perf_counter()
        c = eng.control()
        update_s.append(time.perf_counter() - t0)
        t += 1.0 / fps
        at = setup.poses_at(t)
        eng.advance(t, {name: np.asarray(c.pose), **{n: at[k] for n, k in ks.items()}})
        poses.append(np.asarray(c.pose))
    return np.asarray(poses), update_s


def serve_plate(target: int, seed: int, quick: bool, seconds: float, fps: float) -> dict:
    """The plate scene's bowl ``target`` as a session's send task."""
    from liquidtwin_proto import liquidtwin_pb2 as pb

    from ..control.plate import tilt2_of
    from ..generate.catalog import build_setup
    setup = build_setup("plate_tilt", np.random.default_rng(seed), quick=quick)
    spec, eng = _engine(setup)
    on_plate = eng.volumes()["plate"]
    rest = np.asarray(spec.objects[setup.index("plate")].initial_pose, float)
    t0 = time.perf_counter()
    poses, update_s = _drive(eng, setup, "plate", pb.Task(send=pb.Task.SendToContainer(object="plate",
                                                                                        target=f"bowl{target}")),
                             fps, seconds)
    wall = time.perf_counter() - t0
    vols = eng.volumes()
    in_bowls = [vols[f"bowl{b}"] / on_plate for b in range(8)]
    tilts = np.degrees(np.stack([tilt2_of(p, rest) for p in poses]))
    return {"target": target, "particles": eng.n_particles, "iterations": int(spec.simulation.iterations),
            "caught": in_bowls[target], "in_bowls": in_bowls,
            "spilled": 1.0 - sum(in_bowls), "on_plate": vols["plate"] / on_plate,
            "max_tilt_deg": float(np.abs(tilts).max()), "tilts_deg": tilts.tolist(), "wall_s": wall,
            "update_s": float(np.median(update_s)), "update_s_max": float(np.max(update_s)), "fps": fps}


def serve_catch(motion: int, seed: int, quick: bool, fps: float, controller: str = "mpc") -> dict:
    """Catching source motion ``motion`` as a session's catch task (``controller`` "mpc" or
    "policy": the shipped learned policy)."""
    from liquidtwin_proto import liquidtwin_pb2 as pb

    from ..control.catch import catching_setup
    setup = catching_setup(motion, quick, seed)
    spec, eng = _engine(setup)
    held = eng.volumes()["source"]
    t0 = time.perf_counter()
    poses, update_s = _drive(eng, setup, "catcher", pb.Task(catch_stream=pb.Task.CatchStream(
        source="source", catcher="catcher"), controller=controller), fps, setup.duration, script=("source",))
    wall = time.perf_counter() - t0
    vols = eng.volumes()
    xs = poses[:, 0]
    return {"motion": motion, "direction": setup.notes["direction"], "drift_m_s": setup.notes["drift_m_s"],
            "particles": eng.n_particles, "iterations": int(spec.simulation.iterations), "caught": vols["catcher"] / held,
            "left_source": 1.0 - vols["source"] / held, "spilled": 1.0 - (vols["catcher"] + vols["source"]) / held,
            "xs": xs.tolist(), "travel_m": float(xs.max() - xs.min()), "wall_s": wall,
            "update_s": float(np.median(update_s)), "update_s_max": float(np.max(update_s)), "dt": 1.0 / fps,
            "fps": fps}
