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


class _Ctrl:
    def __init__(self, done: bool):
        self.done = done


def test_top_up_pours_the_rest_once_the_first_pour_has_landed(monkeypatch):
    """PourToVolume.top_up: the decision, with the engine and the MPC stubbed. Nothing happens
    until the source has been upright for LAND_S; then a shortfall above max(1 ml, 10 %) starts
    a new controller for exactly the rest, at most MAX_TOPUPS times, and anything else ends the
    task (done only then)."""
    from types import SimpleNamespace
    from liquidtwin.control.pour import LAND_S
    from liquidtwin.session._task import MAX_TOPUPS, PourTask
    made = []
    monkeypatch.setattr(PourTask, "_mpc", classmethod(lambda cls, eng, *a: made.append(a[-1]) or _Ctrl(False)))
    task = pb.Task(pour=pb.Task.PourToVolume(source="source", target="target", volume_ml=8.0, top_up=True),
                   controller="mpc")
    vols = {"source": 40.0, "target": 2.0 + 5.5}                     # the target held 2 ml when the task was set
    eng = SimpleNamespace(_sim_t=1.0, volumes=lambda: dict(vols))
    pt = PourTask(task, None, 2.0, MAX_ANGLE, MAX_RATE, _Ctrl(True), ["source", "target"])
    pt._top_up(eng, 0.5)                                            # still tilted: wait
    pt._top_up(eng, 0.0)                                            # upright now: the clock starts
    eng._sim_t += 0.9 * LAND_S
    pt._top_up(eng, 0.0)
    assert made == [] and not pt.finished
    eng._sim_t += 0.2 * LAND_S
    pt._top_up(eng, 0.0)                                            # landed, 2.5 ml short: pour the rest
    assert made == [pytest.approx(2.5)] and pt.topups == 1 and not pt.ctrl.done and not pt.finished
    pt.ctrl.done, vols["target"] = True, 2.0 + 7.2                   # 0.8 ml short: within 1 ml, finished
    for dt in (0.0, 1.1 * LAND_S):
        eng._sim_t += dt
        pt._top_up(eng, 0.0)
    assert pt.finished and made == [pytest.approx(2.5)]
    # the limits: MAX_TOPUPS pours more, and never more than the source holds
    for topups, source, finished in ((MAX_TOPUPS, 40.0, True), (0, 1.0, True), (0, 40.0, False)):
        pt = PourTask(task, None, 2.0, MAX_ANGLE, MAX_RATE, _Ctrl(True), ["source", "target"])
        pt.topups, vols["source"], vols["target"] = topups, source, 2.0 + 4.0
        for dt in (0.0, 1.1 * LAND_S):
            eng._sim_t += dt
            pt._top_up(eng, 0.0)
        assert pt.finished == finished


def test_top_up_is_an_mpc_option(spec):
    from liquidtwin.session import EngineError
    eng = SessionEngine.create(pb.SessionSpec(scene=spec, tracking=pb.OPEN_LOOP))
    eng.advance(0.0, {})
    with pytest.raises(EngineError) as err:
        eng.set_task(pb.Task(pour=pb.Task.PourToVolume(source="source", target="target", volume_ml=5.0, top_up=True)))
    assert err.value.code == pb.Error.BAD_REQUEST and "top_up" in str(err.value)
