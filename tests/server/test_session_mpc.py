"""A session's pour task with controller "mpc", closed loop: a simulated robot turns the source
at each Control's rate about the Control's axis, the engine tracks the liquid from those poses,
and the MPC (gradients through the session's model, from the tracked particles) stops the pour
near the ask. The checkpoint continues the controller bit for bit."""

import math
from pathlib import Path

import numpy as np
import pytest
from liquidtwin_proto import liquidtwin_pb2 as pb
from liquidtwin.recordings import read_recording
from liquidtwin.control.tilt import tilt_from_upright, turn_pose
from session_restore import restored_copy
from liquidtwin.session import SessionEngine

GOLDEN = Path(__file__).parent / "data" / "golden_pour_dump.mcap"
FPS = 30.0
MAX_ANGLE, MAX_RATE = 2.0, 1.5


def robot_turn(pose: np.ndarray, c: pb.Control, dt: float) -> np.ndarray:
    """The source's pose after turning it for dt s at the commanded rate about the Control's
    axis, its tilt kept in [0, MAX_ANGLE] (what a robot arm told this would do)."""
    tilt = tilt_from_upright(pose)
    turn = min(max(tilt + c.tilt_rate_rad_s * dt, 0.0), MAX_ANGLE) - tilt
    return turn_pose(pose, c.axis_point_m, c.axis_direction, turn)


@pytest.fixture(scope="module")
def spec():
    return read_recording(GOLDEN, images=False).spec


def test_mpc_task_pours_the_ask_closed_loop_and_checkpoints(spec):
    eng = SessionEngine.create(pb.SessionSpec(scene=spec, tracking=pb.OPEN_LOOP))
    eng.advance(0.0, {})
    held = eng.volumes()["source"]
    assert abs(held - 23.0) < 0.03 * 23.0
    ask = 8.0
    eng.set_task(pb.Task(pour=pb.Task.PourToVolume(source="source", target="target", volume_ml=ask,
                                                   max_angle_rad=MAX_ANGLE, max_rate_rad_s=MAX_RATE),
                         controller="mpc"))
    pose = np.asarray(spec.objects[0].initial_pose, float)
    dt, t, done_at, top = 1.0 / FPS, 0.0, None, 0.0
    for i in range(int(5.0 * FPS)):
        c = eng.control()
        assert c.controller == "mpc" and c.object == "source"
        assert 0.0 <= c.tilt_angle_rad <= MAX_ANGLE and abs(c.tilt_rate_rad_s) <= MAX_RATE + 1e-9
        axis = np.asarray(c.axis_direction)
        assert abs(np.linalg.norm(axis) - 1.0) < 1e-9 and abs(axis[1]) < 1e-9      # horizontal
        if i == 5:                                 # mid-task: a checkpoint continues it bit for bit
            other = restored_copy(eng, spec)
            assert other.control() == c
            nxt = robot_turn(pose, c, dt)
            for e in (eng, other):
                e.advance(t + dt, {"source": nxt})
            assert other.control() == eng.control()
            assert np.array_equal(other.positions(), eng.positions())
            del other
            pose, t = nxt, t + dt
            continue
        if c.done and done_at is None:
            done_at = t
        if done_at is not None and t > done_at + 1.5 and tilt_from_upright(pose) < 1e-6:
            break
        pose = robot_turn(pose, c, dt)
        top = max(top, tilt_from_upright(pose))
        t += dt
        eng.advance(t, {"source": pose})
    c = eng.control()
    print(f"asked {ask} ml, poured {c.achieved_ml:.2f} ml, top tilt {math.degrees(top):.0f} deg, "
          f"switched at {done_at} s")
    assert done_at is not None and c.done and tilt_from_upright(pose) < 1e-6
    assert top > math.radians(60)                  # it did tilt until the liquid flowed
    # This dump cup lets its liquid go in slugs of up to ~3 ml a frame; switch-now vs
    # switch-next keeps the error below one slug (8.87 ml measured; the PD baseline pours all 22).
    assert abs(c.achieved_ml - ask) < 2.0, c.achieved_ml
    vols = eng.volumes()
    assert vols["source"] + vols["target"] > 0.9 * held      # little spilled beside the pan
