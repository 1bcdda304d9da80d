"""A session's catch and send tasks (MPC through the session's model, served once per frame),
closed loop with a simulated robot that puts the controlled object where each Control's
``pose`` says, the rest of the scene on its script; the world is the session's own model.
Also the geometry they rest on (the screw extrapolation of the source's motion, the plate
tilt's inverse) against independent constructions, and the refusals of impossible tasks."""

import math

import numpy as np
import pytest
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from liquidtwin.control.catch import catching_setup, extrapolate_pose
from liquidtwin.control.plate import tilt2_of, tilt2_space
from liquidtwin.control.tilt import turn_pose
from liquidtwin.generate.catalog import build_setup
from liquidtwin.generate.generator import scene_spec
from liquidtwin.scenes.motions import quat_axis_angle
from realisations import SKINS, realisation
from session_restore import restored_copy
from liquidtwin.session import EngineError, SessionEngine

FPS = 30.0


def test_extrapolation_continues_a_screw_motion():
    """A body turning at a constant rate about a fixed axis while sliding along it: from its
    poses at two times, the extrapolation lands on the pose the motion reaches later."""
    rng = np.random.default_rng(4)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    point, start = rng.normal(size=3) * 0.1, np.concatenate([rng.normal(size=3) * 0.1, quat_axis_angle(rng.normal(size=3), 0.7)])
    rate, slide = 1.3, 0.2                              # rad/s, m/s along the axis

    def at(t):
        p = turn_pose(start, point, axis, rate * t)
        p[:3] += slide * t * axis
        return p

    for s in (0.5, 3.0, -1.0):
        got = extrapolate_pose(at(0.1), at(0.15), s)
        want = at(0.15 + s * 0.05)
        assert np.allclose(got[:3], want[:3], atol=1e-9)
        assert min(np.abs(got[3:] - want[3:]).max(), np.abs(got[3:] + want[3:]).max()) < 1e-9
    # no turn: a constant velocity
    a, b = start.copy(), start.copy()
    b[:3] += [0.01, -0.02, 0.0]
    assert np.allclose(extrapolate_pose(a, b, 2.0)[:3], start[:3] + [0.03, -0.06, 0.0])


def test_tilt_readback_inverts_the_two_axis_tilt():
    rest = np.concatenate([[0.1, 0.2, -0.1], quat_axis_angle([0.3, 1.0, 0.2], 0.8)])
    space = tilt2_space(rest[None], 0)
    for q in ([0.3, 0.0], [0.0, -0.4], [0.5, 0.6], [-0.7, 0.2]):
        pose = space.to_pose(torch.tensor([q], dtype=torch.float64))[0].numpy()
        assert np.allclose(pose[:3], rest[:3])
        assert np.allclose(tilt2_of(pose, rest), q, atol=1e-12)


def _catch_engine(motion: int, fraction: float):
    setup = catching_setup(motion)
    spec = scene_spec(setup)
    spec.fills[0].volume_ml = fraction * spec.fills[0].volume_ml
    eng = SessionEngine.create(pb.SessionSpec(scene=spec, tracking=pb.OPEN_LOOP))
    eng.advance(0.0, {})
    return setup, spec, eng


def _serve_catch(controller: str) -> tuple[float, float]:
    """One served catch of source motion 3 at a fifth of the fill, with every control checked
    against the task's limits and a mid-pour checkpoint that continues bit for bit: (share
    caught, share a catcher left where it starts catches)."""
    setup, spec, eng = _catch_engine(3, 0.2)
    _, _, still = _catch_engine(3, 0.2)
    src = setup.index("source")
    held = eng.volumes()["source"]
    eng.set_task(pb.Task(catch_stream=pb.Task.CatchStream(source="source", catcher="catcher"), controller=controller))
    pose = np.asarray(spec.objects[setup.index("catcher")].initial_pose, float)
    x0, dt, t, i = pose[0], 1.0 / FPS, 0.0, 0
    while t < setup.duration:
        c = eng.control()
        assert c.object == "catcher" and c.controller == controller and len(c.pose) == 7
        assert abs(c.linear_velocity_m_s[0]) <= 0.5 + 1e-9 and abs(c.pose[0] - x0) <= 0.3 + 1e-9
        assert np.allclose(c.pose[1:], pose[1:])                 # it only slides along x
        nxt, t = np.asarray(c.pose), t + dt
        if i == 20:                                               # mid-pour: a checkpoint continues bit for bit
            other = restored_copy(eng, spec)
            assert other.control() == c
            for e in (eng, other):
                e.advance(t, {"source": setup.poses_at(t)[src], "catcher": nxt})
            assert other.control() == eng.control()
            assert np.array_equal(other.positions(), eng.positions())
            del other
        else:
            eng.advance(t, {"source": setup.poses_at(t)[src], "catcher": nxt})
        still.advance(t, {"source": setup.poses_at(t)[src]})
        pose, i = nxt, i + 1
    caught, still_caught = eng.volumes()["catcher"] / held, still.volumes()["catcher"] / held
    c = eng.control()
    print(f"caught {caught:.3f} of {held:.2f} ml (a still catcher: {still_caught:.3f}); catcher "
          f"{100 * x0:.1f} → {100 * pose[0]:.1f} cm; done {c.done}")
    assert eng.volumes()["source"] < 0.05 * held                  # the pour happened
    assert c.achieved_ml == pytest.approx(eng.volumes()["catcher"])
    return caught, still_caught


@pytest.mark.parametrize("controller", ["mpc", "policy"])
def test_catch_task_catches_a_moving_stream_closed_loop_and_checkpoints(controller):
    """Source motion 3 (pours towards −x, the stream lands ~8.5 cm from the catcher's start),
    a fifth of the fill: the served MPC, and the learned policy, catch far more than a catcher
    left where it starts, on average over three realisations of the pour's chaos
    (``realisations.SKINS``)."""
    runs = []
    for skin in SKINS:
        with realisation(skin):
            runs.append(_serve_catch(controller))
    caught, still = np.mean(runs, axis=0)
    # Measured over five skins (0, 0.05, 0.1, 0.2, 0.3 h; bench/perturbed.py), caught / a still
    # catcher: MPC 0.963/0.716, 0.973/0.649, 0.872/0.670, 0.917/0.667, 0.973/0.645 (mean
    # difference 0.27); policy 0.908/0.716, 0.883/0.649, 0.881/0.670, 0.944/0.667, 0.818/0.645
    # (0.22). The still catcher's share alone moves by 0.07 between runs. Asserted on the means
    # over SKINS: above 85 %, and above the still catcher by half the policy's difference.
    assert caught > 0.85 and caught > still + 0.1, runs


def test_send_task_tips_the_plate_into_the_target_bowl():
    setup = build_setup("plate_tilt", np.random.default_rng(0), quick=True)
    spec = scene_spec(setup)
    eng = SessionEngine.create(pb.SessionSpec(scene=spec, tracking=pb.OPEN_LOOP))
    eng.advance(0.0, {})
    on_plate = eng.volumes()["plate"]
    eng.set_task(pb.Task(send=pb.Task.SendToContainer(object="plate", target="bowl3")))
    k = setup.index("plate")
    t, top = 0.0, 0.0
    for _ in range(int(1.5 * FPS)):
        c = eng.control()
        assert c.object == "plate" and len(c.pose) == 7 and len(c.angular_velocity_rad_s) == 3
        pose, t = np.asarray(c.pose), t + 1.0 / FPS
        q = tilt2_of(pose, spec.objects[k].initial_pose)
        assert np.abs(q).max() <= math.radians(45) + 1e-9
        top = max(top, float(np.abs(q).max()))
        eng.advance(t, {"plate": pose})
    vols = {n: v / on_plate for n, v in eng.volumes().items()}
    print({n: round(v, 3) for n, v in vols.items() if v > 0}, f"top tilt {math.degrees(top):.0f} deg")
    assert max(vols, key=vols.get) == "bowl3" and vols["bowl3"] > 0.5
    assert top > math.radians(15)                                 # it did tip


@pytest.fixture(scope="module")
def catch_scene():
    return _catch_engine(0, 0.2)[2]


@pytest.mark.parametrize("task, code, words", [
    (pb.Task(catch_stream=pb.Task.CatchStream(source="source", catcher="nothing")), "UNKNOWN_NAME", "nothing"),
    (pb.Task(catch_stream=pb.Task.CatchStream(source="source", catcher="table")), "BAD_REQUEST", "not a container"),
    (pb.Task(catch_stream=pb.Task.CatchStream(source="source", catcher="source")), "BAD_REQUEST", "twice"),
    (pb.Task(catch_stream=pb.Task.CatchStream(source="catcher", catcher="source")), "INFEASIBLE", "no liquid"),
    (pb.Task(catch_stream=pb.Task.CatchStream(source="source", catcher="catcher"), controller="pid"), "BAD_REQUEST",
     "'mpc', 'policy', got 'pid'"),
    (pb.Task(send=pb.Task.SendToContainer(object="source", target="catcher"), controller="policy"), "BAD_REQUEST",
     "'mpc', got 'policy'"),
    (pb.Task(catch_stream=pb.Task.CatchStream(source="source", catcher="catcher", max_speed_m_s=-1)), "BAD_REQUEST",
     "max_speed_m_s"),
    (pb.Task(catch_stream=pb.Task.CatchStream(source="source", catcher="catcher", range_m=float("nan"))),
     "BAD_REQUEST", "range_m"),
    (pb.Task(send=pb.Task.SendToContainer(object="catcher", target="source")), "INFEASIBLE", "no liquid"),
    (pb.Task(send=pb.Task.SendToContainer(object="source", target="catcher", max_angle_rad=2.0)), "BAD_REQUEST",
     "max_angle_rad"),
])
def test_impossible_catch_and_send_tasks_are_refused(catch_scene, task, code, words):
    eng = catch_scene
    with pytest.raises(EngineError) as err:
        eng.set_task(task)
    assert pb.Error.Code.Name(err.value.code) == code and words in str(err.value), str(err.value)
    assert eng.control() is None                                  # nothing was set


def test_a_control_task_on_a_session_that_cannot_hold_its_falls_warns():
    """A catch task set on the catching scene's session at its stated 4 iterations warns that
    liquid falling 32 cm needs 11 (sim.iterations_for_impact); the same spec solved with 11
    (scenes.spec.solve_with: the same liquid) does not."""
    import warnings

    from liquidtwin.scenes.spec import solve_with
    task = pb.Task(catch_stream=pb.Task.CatchStream(source="source", catcher="catcher"))
    setup, spec, eng = _catch_engine(3, 0.2)
    assert spec.simulation.iterations == 4
    with pytest.warns(RuntimeWarning, match=r"fall 32 cm .*simulation.iterations >= 11 \(reference_iterations 4"):
        eng.set_task(task)
    spec11 = solve_with(scene_spec(setup), 11)
    spec11.fills[0].volume_ml = spec.fills[0].volume_ml
    eng11 = SessionEngine.create(pb.SessionSpec(scene=spec11, tracking=pb.OPEN_LOOP))
    eng11.advance(0.0, {})
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        eng11.set_task(task)
