"""The catching task (control.catch): the 8 source motions pour the way and drift the way
they say; the control moves only the catcher; the MPC slides the catcher under the stream and
catches most of a small pour (quick scene, a fifth of its fill)."""

import math

import numpy as np
import pytest
import torch

from liquidtwin.control.catch import SOURCE_MOTIONS, catch_space, catching_setup, run_catch
from liquidtwin.control.mpc import ControlError
from liquidtwin.generate.world import model_for
from liquidtwin.scenes.fill import fill_container
from liquidtwin.scenes.motions import quat_matrix
from liquidtwin.scenes.liquid_level import held
from liquidtwin.sim import step
from realisations import SKINS, realisation


@pytest.mark.parametrize("motion", range(len(SOURCE_MOTIONS)))
def test_source_motions_pour_towards_their_side_and_drift(motion):
    direction, drift = SOURCE_MOTIONS[motion]
    setup = catching_setup(motion)
    k = setup.index("source")
    pour = setup.objects[k].motion
    start, end = pour.angle.times[1], pour.end
    lip0, lip1 = pour.path(0.0), pour.path(end)
    assert lip1[0] - lip0[0] == pytest.approx(drift * (end - start), abs=1e-9)
    assert np.allclose(lip1[1:], lip0[1:])
    # at full tilt the cup's +y points towards the pour side
    up = quat_matrix(setup.poses_at(pour.angle.times[2])[k][3:])[:, 1]
    assert np.sign(up[0]) == direction and up[1] < math.cos(math.radians(60))
    # the pivot (lip) is the rim point on that side
    assert np.sign(pour.pivot[0]) == direction
    with pytest.raises(ControlError):
        catching_setup(len(SOURCE_MOTIONS))


def test_the_control_moves_only_the_catcher():
    setup = catching_setup(0)
    space = catch_space(setup, 0.5, 4, setup.dt)
    q = torch.tensor([[-0.05], [0.0], [0.05], [0.1]], dtype=torch.float64)
    poses = space.poses(q)
    k = setup.index("catcher")
    for i in range(4):
        scene = torch.as_tensor(setup.poses_at(0.5 + (i + 1) * setup.dt))
        others = [j for j in range(scene.shape[0]) if j != k]
        assert torch.allclose(poses[i, others], scene[others])
        assert float(poses[i, k, 0]) == pytest.approx(float(q[i, 0]))
        assert torch.allclose(poses[i, k, 1:], scene[k, 1:])


def _catch_and_stay(motion: int):
    """One MPC catch of ``motion`` at a fifth of the fill, and the same pour with the catcher
    left where it starts (below the lip): (CatchRun, share the still catcher holds, particles)."""
    setup = catching_setup(motion)
    model = model_for(setup)
    k = setup.index("source")
    state, _ = fill_container(model, torch.as_tensor(setup.poses_at(0.0)), k, setup.objects[k].model,
                              volume_ml=0.2 * dict(setup.fills)["source"], settle_s=0.3)
    r = run_catch(setup, model, state)
    s = state
    steps = int(round(setup.duration / model.dt))
    with torch.no_grad():
        for i in range(steps):
            s = step(model, s, torch.as_tensor(setup.poses_at((i + 1) * model.dt)).to(s.x))
    kc = setup.index("catcher")
    still = float(held(model, s, kc, setup.objects[kc].model)[0].sum()) / s.x.shape[0]
    print(f"{state.x.shape[0]} particles: caught {r.caught:.3f} (a still catcher: {still:.3f}), left the source "
          f"{r.left_source:.3f}, catcher {100 * r.xs[0]:.1f} → {100 * r.xs[-1]:.1f} cm")
    return r, still


def test_mpc_slides_the_catcher_under_the_stream():
    """Motion 3 pours towards −x and lands ~8.5 cm from the catcher's start. Over three
    realisations of the pour's chaos (``realisations.SKINS``)."""
    caught, still = [], []
    for skin in SKINS:
        with realisation(skin):
            r, s = _catch_and_stay(3)
        assert r.left_source > 0.9                          # the pour happened
        assert r.caught > 0.85, r.caught
        caught.append(r.caught)
        still.append(s)
    # Measured over five skins (0, 0.05, 0.1, 0.2, 0.3 h; bench/perturbed.py), caught / a still
    # catcher: 0.936/0.645, 0.963/0.611, 0.973/0.554, 0.946/0.784, 0.927/0.682 (the difference
    # 0.16–0.42, mean 0.29: most of the spread is the still catcher's). Asserted on the means
    # over SKINS: half the measured difference.
    assert np.mean(caught) > np.mean(still) + 0.15, (caught, still)


def test_the_first_landing_prediction_matches_where_the_stream_crosses_the_rim():
    """first_landing (a model rollout plus the ballistic flight) against a brute-force record
    of where each particle crosses the catcher's rim height in a longer rollout."""
    from liquidtwin.control.catch import FALLING_MIN, first_landing
    setup = catching_setup(0)
    model = model_for(setup)
    k, kc = setup.index("source"), setup.index("catcher")
    state, _ = fill_container(model, torch.as_tensor(setup.poses_at(0.0)), k, setup.objects[k].model,
                              volume_ml=0.3 * dict(setup.fills)["source"], settle_s=0.3)
    rim_y = float(setup.poses_at(0.0)[kc][1]) + float(setup.objects[kc].model.rim_height)
    x_catcher = float(setup.poses_at(0.0)[kc][0])
    s, crossed, i, predicted = state, {}, 0, float("nan")
    n = state.x.shape[0]
    with torch.no_grad():
        while len(crossed) < max(FALLING_MIN * n, 3) and i < 300:
            if i % 6 == 0 and math.isnan(predicted):
                predicted = first_landing(setup, model, s, i * model.dt, x_catcher)
            prev = dict(zip(s.ids.tolist(), s.x[:, 1].tolist()))
            poses = torch.as_tensor(setup.poses_at((i + 1) * model.dt))
            s = step(model, s, poses.to(s.x))
            i += 1
            for pid, x, y in zip(s.ids.tolist(), s.x[:, 0].tolist(), s.x[:, 1].tolist()):
                if prev[pid] > rim_y >= y and pid not in crossed:
                    crossed[pid] = x
    actual = float(np.median(list(crossed.values())))
    print(f"\npredicted first landing {100 * predicted:.1f} cm, measured {100 * actual:.1f} cm "
          f"(catcher at {100 * x_catcher:.1f} cm, stream after {i} steps)")
    assert not math.isnan(predicted) and abs(predicted - actual) < 0.015
    assert actual < x_catcher - 0.08                 # far enough that waiting for the stream loses liquid


def test_the_control_tasks_solve_their_falls_with_more_iterations_of_the_same_liquid():
    """control_model: the scene model's liquid (same cohesion, h, dt, objects) solved with the
    iterations a free fall from the highest rim needs (sim.iterations_for_impact)."""
    from liquidtwin.control.plate import plate_scene
    from liquidtwin.evaluate.served import _engine
    from liquidtwin.generate.world import control_model, fall_height, impact_iterations, model_iterations
    from liquidtwin.sim import iterations_for_impact
    setup = catching_setup(7)
    src, dst = setup.index("source"), setup.index("catcher")
    p0 = setup.poses_at(0.0)
    assert fall_height(setup) == pytest.approx(p0[src][1] + setup.objects[src].model.rim_height - p0[dst][1])
    speed = math.sqrt(2 * 9.81 * fall_height(setup))               # 2.5 m/s onto the catcher's floor
    assert impact_iterations(setup) == iterations_for_impact(speed, setup.dt, 0.55 * setup.h) == 11
    base, ctrl = model_for(setup), control_model(setup)
    assert (ctrl.iterations, ctrl.reference_iterations) == (11, model_iterations(setup)) == (11, base.iterations)
    assert (ctrl.h, ctrl.dt, ctrl.kappa, ctrl.relaxation) == (base.h, base.dt, base.kappa, base.relaxation)
    assert ctrl.params.as_dict() == base.params.as_dict()
    plate_setup, plate_model, _ = plate_scene(0, True)
    assert plate_model.iterations == impact_iterations(plate_setup) == 8   # a 16.7 cm fall
    spec, _ = _engine(setup)                                        # a served task's session
    assert (spec.simulation.iterations, spec.simulation.reference_iterations) == (11, model_iterations(setup))
