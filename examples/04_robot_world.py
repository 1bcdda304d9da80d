"""A headless robot world that pours (or catches) through a running liquidtwin server, closed loop.

The world (``liquidtwin.generate.robot.RobotWorld``) is the generator's true physics with a
hidden effect (drawn from ``--seed`` unless given) and sensor noise. Every frame the robot
sends the server its thermal camera's liquid mask and its tracked poses, waits for the
session's Control and turns the source as told (the commanded rate about the Control's axis,
within the task's limits), then lets the world run one frame. When the controller is done and
the source is upright again, it reports what the target *truly* holds — the world's own
count, which the server never sees.

With ``--task catch`` the scene is the catching one: the robot pours from the source on the
scene's script (the server does not know it) and slides the catcher at each Control's
velocity; at the end it reports the share of the liquid the catcher truly holds.

    liquidtwin serve --listen tcp/127.0.0.1:7447 &
    python examples/04_robot_world.py --connect tcp/127.0.0.1:7447 --ml 8 --controller mpc \\
        --effect drag --seed 3 --out robot.json
    python examples/04_robot_world.py --connect tcp/127.0.0.1:7447 --task catch --seed 1
"""

import argparse
import json
import math
import sys
import time

from tqdm.auto import tqdm

from liquidtwin.control.tilt import turn_pose
from liquidtwin.generate.robot import RobotWorld
from liquidtwin.scenes.spec import solve_with
from liquidtwin_client import Client
from liquidtwin_proto import liquidtwin_pb2 as pb

#: A pour counts once the source tilts past this, rad (20°).
POUR_TILT = math.radians(20.0)
#: Stamps start here (2026-01-01T00:00:00Z), like the generator's recordings.
START_NS = 1_767_225_600_000_000_000


def effect_arg(text: str):
    """NAME or NAME=VALUE → (name, value or None: drawn from the seed)."""
    name, _, value = text.partition("=")
    return (name, float(value) if value else None)


#: The server's latest volumes, {container: (particle-count ml, mask-model ml or None)}.
VOLUMES: dict = {}


def wait_control(session, stamp: int, timeout: float):
    """The Control answering the frame stamped ``stamp`` (volumes are kept in ``VOLUMES``,
    other outputs skipped)."""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        out = session.next_output(timeout=left)
        if out is not None and out.stream == "volumes":
            VOLUMES.update({c.name: (c.ml, c.mask_ml if c.HasField("mask_ml") else None)
                            for c in out.message.containers})
        if out is not None and out.stream == "control" and out.header.stamp_ns == stamp:
            return out.message
    raise TimeoutError(f"no control for the frame stamped {stamp} within {timeout} s")


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--connect", default="tcp/127.0.0.1:7447", help="server endpoint (default: %(default)s)")
    p.add_argument("--task", default="pour", choices=("pour", "catch"), help="(default: %(default)s)")
    p.add_argument("--scene", default=None, help="scene (default: pour_dump; catching for --task catch)")
    p.add_argument("--source", default="cup", help="source container model (default: %(default)s)")
    p.add_argument("--target", default="pan", help="target container model (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="world, effect and noise (default: %(default)s)")
    p.add_argument("--effect", type=effect_arg, action="append", default=[],
                   help="hidden effect NAME or NAME=VALUE (repeatable; default: none)")
    p.add_argument("--no-noise", action="store_true", help="perfect sensors")
    p.add_argument("--ml", type=float, default=8.0, help="ml to pour (default: %(default)s)")
    p.add_argument("--controller", default="mpc", choices=("pid", "mpc", "policy"),
                   help="pour: pid or mpc; catch: mpc or policy (the server's learned catching policy) "
                        "(default: %(default)s)")
    p.add_argument("--tracking", default="warp_field", help="session tracker (default: %(default)s)")
    p.add_argument("--iterations", type=int, default=None,
                   help="PBF solver iterations the robot asks of the session's model, for the same liquid "
                        "(cohesion as the scene's count applies it; default: the scene's count)")
    p.add_argument("--top-up", action="store_true",
                   help="pour: the MPC pours again when the twin's target ends short of the ask")
    p.add_argument("--pose-filter", action="store_true",
                   help="ask the session to filter the tracked poses (its tracker's stated noise)")
    p.add_argument("--fps", type=float, default=30.0, help="frames per s (default: %(default)s)")
    p.add_argument("--max-angle", type=float, default=2.0, help="tilt limit, rad (default: %(default)s)")
    p.add_argument("--max-rate", type=float, default=1.5, help="rate limit, rad/s (default: %(default)s)")
    p.add_argument("--seconds", type=float, default=6.0, help="longest run, s (default: %(default)s)")
    p.add_argument("--full", action="store_true",
                   help="pour: run all --seconds instead of stopping 1.5 s after the task is done and the "
                        "source upright (so runs compare at one time: landed liquid can still splash out)")
    p.add_argument("--timeout", type=float, default=60.0, help="longest wait for a control, s (default: %(default)s)")
    p.add_argument("--out", help="write the result as JSON here")
    a = p.parse_args(argv)

    if a.task == "catch":
        if a.controller == "pid":
            p.error("--task catch runs --controller mpc or policy")
        return catch(a)
    if a.controller == "policy":
        p.error("--controller policy is a catching policy: use it with --task catch")
    world = RobotWorld(a.scene or "pour_dump", seed=a.seed, quick=True, effects=a.effect, noise=not a.no_noise,
                       choices={"source": a.source, "target": a.target})
    before = world.held_ml()
    frame_ns = int(round(1e9 / a.fps))
    dt = frame_ns * 1e-9
    done_at, top, frames, pours, tilted = None, 0.0, 0, 0, False
    t0 = time.perf_counter()
    with Client(connect=a.connect) as client:
        session, cams = open_session(client, world, a.tracking, a.iterations, a.pose_filter)
        session.set_pour_task("source", "target", a.ml, a.max_angle, a.max_rate, controller=a.controller,
                              top_up=a.top_up)
        bar = tqdm(range(int(a.seconds * a.fps)), desc=f"{a.controller} {a.ml:g} ml", unit="frame")
        for i in bar:
            c = exchange(session, world, cams, START_NS + i * frame_ns, a.timeout)
            frames += 1
            tilt = world.tilt("source")
            if tilt > POUR_TILT and not tilted:
                pours += 1
            tilted = tilt > POUR_TILT
            if c.done and done_at is None:
                done_at = world.t
            if not a.full and done_at is not None and world.t > done_at + 1.5 and tilt < 1e-6:
                break
            turn = min(max(tilt + c.tilt_rate_rad_s * dt, 0.0), a.max_angle) - tilt
            pose = turn_pose(world.poses[world.setup.index("source")], c.axis_point_m, c.axis_direction, turn)
            world.move({"source": pose}, dt)
            top = max(top, world.tilt("source"))
            bar.set_postfix(tilt=f"{math.degrees(tilt):.0f}", achieved=f"{c.achieved_ml:.1f}")
        session.close()
    after = world.held_ml()
    result = {"controller": a.controller, "ask_ml": a.ml, "poured_ml": after["target"] - before["target"],
              "server_achieved_ml": c.achieved_ml, "source_before_ml": before["source"],
              "spilled_ml": before["source"] + before["target"] - after["source"] - after["target"],
              "switched_s": done_at, "upright": bool(world.tilt("source") < 1e-6),
              "max_tilt_deg": math.degrees(top), "frames": frames, "wall_s": time.perf_counter() - t0,
              "scene": world.setup.name, "seed": a.seed, "effects": [e.as_dict() for e in world.effects],
              "model_iterations": a.iterations or world.spec().simulation.iterations, "pose_filter": a.pose_filter,
              "top_up": a.top_up, "pours": pours, "seconds": world.t, "server_volumes_ml": dict(VOLUMES), "true_held_ml": after}
    print(f"asked {a.ml:g} ml, poured {result['poured_ml']:.2f} ml (the server thought "
          f"{c.achieved_ml:.2f}), spilled {result['spilled_ml']:.2f} ml, {frames} frames")
    return save(result, a.out)


def open_session(client, world, tracking: str, iterations: int | None = None, pose_filter: bool = False):
    """A session of the world's stated scene (its model solving ``iterations`` PBF iterations
    a step if given; its poses filtered with the tracker's stated noise if ``pose_filter``),
    its cameras' calibrations sent."""
    spec = world.spec()
    if iterations is not None:
        try:
            solve_with(spec, iterations)
        except ValueError as e:
            raise SystemExit(f"--iterations: {e}") from None
    session_spec = pb.SessionSpec(scene=spec)
    if pose_filter:
        noise = world.pose_noise
        session_spec.pose_filter.CopyFrom(pb.PoseFilter(position_noise_m=noise.pos_sigma_m,
                                                        rotation_noise_rad=noise.rot_sigma_rad))
    session = client.create_session(session_spec, tracking=tracking)
    cams = world.cameras()
    for name, c in cams.items():
        session.publish_camera(name, c.K, c.D, c.width, c.height, START_NS)
    return session, cams


def exchange(session, world, cams, stamp: int, timeout: float):
    """One frame: send what the sensors report now (masks, then poses), return the Control."""
    poses, masks = world.sense()
    for name, mask in masks.items():
        session.publish_mask(name, mask, stamp)
    session.publish_poses({**poses, **{n: c.pose for n, c in cams.items()}}, stamp)
    return wait_control(session, stamp, timeout)


def save(result: dict, out) -> dict:
    if out:
        with open(out, "w") as f:
            json.dump(result, f, indent=2)
    return result


def catch(a) -> dict:
    """--task catch: the source pours on its script; the catcher moves at each Control's velocity."""
    world = RobotWorld(a.scene or "catching", seed=a.seed, quick=True, effects=a.effect, noise=not a.no_noise)
    before = world.held_ml()
    src, dst = world.setup.index("source"), world.setup.index("catcher")
    frame_ns = int(round(1e9 / a.fps))
    dt = frame_ns * 1e-9
    x0, frames, t0 = float(world.poses[dst][0]), 0, time.perf_counter()
    with Client(connect=a.connect) as client:
        session, cams = open_session(client, world, a.tracking, a.iterations, a.pose_filter)
        session.set_catch_task("source", "catcher", controller=a.controller)
        bar = tqdm(range(int(round(world.setup.duration * a.fps))), desc="catch", unit="frame")
        for i in bar:
            c = exchange(session, world, cams, START_NS + i * frame_ns, a.timeout)
            frames += 1
            pose = world.poses[dst].copy()               # a velocity-controlled robot: its own pose + v·dt
            pose[:3] += [v * dt for v in c.linear_velocity_m_s]
            world.move({"catcher": pose, "source": world.setup.poses_at(world.t + dt)[src]}, dt)
            bar.set_postfix(x=f"{100 * pose[0]:.1f}cm", caught=f"{c.achieved_ml:.1f}")
        session.close()
    after = world.held_ml()
    result = {"task": "catch", "source_before_ml": before["source"], "caught_ml": after["catcher"] - before["catcher"],
              "caught": (after["catcher"] - before["catcher"]) / before["source"], "left_in_source_ml": after["source"],
              "server_achieved_ml": c.achieved_ml, "catcher_start_x_m": x0, "catcher_end_x_m": float(world.poses[dst][0]),
              "frames": frames, "wall_s": time.perf_counter() - t0, "scene": world.setup.name, "seed": a.seed,
              "effects": [e.as_dict() for e in world.effects], "pose_filter": a.pose_filter,
              "controller": a.controller, "server_volumes_ml": dict(VOLUMES), "true_held_ml": after}
    print(f"caught {result['caught_ml']:.2f} of {before['source']:.2f} ml ({100 * result['caught']:.1f} %; the server "
          f"thought {c.achieved_ml:.2f}), catcher {100 * x0:.1f} -> {100 * result['catcher_end_x_m']:.1f} cm, "
          f"{frames} frames")
    return save(result, a.out)


if __name__ == "__main__":
    main()
    sys.exit(0)
