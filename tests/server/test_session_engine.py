"""SessionEngine: the golden pour replayed open loop and with the warp field (IOU, volumes
against the truth sidecar), checkpoints that continue bit for bit, frames, tasks, errors."""

import io
import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb
from liquidtwin.camera import iou
from liquidtwin.recordings import read_recording
from liquidtwin.session.engine import held_count
from liquidtwin.session import (BACKGROUND_RGB, MODEL_RGB, OBSERVED_RGB, OVERLAP_RGB, EngineError, SessionEngine,
                                make_overlay)
from liquidtwin.sim import make_state
from realisations import SKINS, realisation

DATA = Path(__file__).parent / "data"
GOLDEN = DATA / "golden_pour_dump.mcap"
CAMERA = "thermal"
LIQUID_PX = 50      # frames whose mask shows at least this much liquid count in the mean IOU


@pytest.fixture(scope="module")
def rec():
    return read_recording(GOLDEN, images=False)


def _engine(rec, tracking=pb.WARP_FIELD, **kw) -> SessionEngine:
    eng = SessionEngine.create(pb.SessionSpec(scene=rec.spec, tracking=tracking, **kw))
    cam = rec.cameras[CAMERA]
    eng.set_camera(CAMERA, K=cam.K, D=cam.D, width=cam.width, height=cam.height, pose=cam.pose)
    return eng


def _frame(eng, rec, i):
    """Feed pose sample i (and the mask stamped with it): (FrameResult, CorrectionResult or None)."""
    t = rec.pose_times_ns[i]
    res = eng.advance((t - rec.pose_times_ns[0]) * 1e-9, dict(zip(rec.object_names, rec.poses[i])))
    stamps, masks = rec.masks[CAMERA]
    j = int(np.searchsorted(stamps, t))
    corr = eng.correct(CAMERA, masks[j]) if j < len(stamps) and stamps[j] == t else None
    return res, corr


def _true_volumes(eng, rec, frame_stamp):
    """Truth: true particles inside each container × the truth's ml per particle."""
    z = np.load(GOLDEN.with_suffix(".truth.npz"))
    truth = json.loads(GOLDEN.with_suffix(".truth.json").read_text())
    ml = truth["fill_ml"]["reports"]["source"]["particle_volume_ml"]
    k = int(np.searchsorted(z["pose_stamps_ns"], frame_stamp))
    state = make_state(z["particles"][k], poses=z["true_poses"][k])
    model = eng._scene.model
    return {name: held_count(model, state, eng.object_names.index(name), eng._scene.objects[
        eng.object_names.index(name)]) * ml for name in eng.container_names}


def _replay(eng, rec):
    ious, vol_err, frame_ms = [], [], []
    stamps = rec.masks[CAMERA][0]
    for i in range(len(rec.pose_times_ns)):
        start = time.perf_counter()
        res, corr = _frame(eng, rec, i)
        frame_ms.append(1e3 * (time.perf_counter() - start))
        if corr is not None:
            if corr.observed_px >= LIQUID_PX:
                ious.append(corr.iou)
            if rec.pose_times_ns[i] in stamps[::4] or rec.pose_times_ns[i] == stamps[-1]:   # every 4th and the last
                truth, est = _true_volumes(eng, rec, rec.pose_times_ns[i]), eng.volumes()
                vol_err.append(max(abs(est[n] - truth[n]) for n in truth))
    return np.array(ious), np.array(vol_err), np.array(frame_ms)


def test_warp_field_tracks_the_golden_pour_better_than_open_loop(rec):
    """Averaged over three realisations of the model's chaos (``realisations.SKINS``: the same
    physics in another float rounding; the recording is the same file)."""
    gains, open_last, warp_last = [], [], []
    for skin in SKINS:
        with realisation(skin):
            open_iou, open_vol, open_ms = _replay(_engine(rec, pb.OPEN_LOOP), rec)
            warp = _engine(rec)                              # TRACKING_MODE_UNSPECIFIED would give the same
            warp_iou, warp_vol, warp_ms = _replay(warp, rec)
        print(f"\nskin {skin} h: mean IOU over {len(open_iou)} liquid frames: open loop {open_iou.mean():.3f}, "
              f"warp field {warp_iou.mean():.3f}; max volume error open {open_vol.max():.2f} ml, "
              f"warp {warp_vol.max():.2f} ml, at the end open {open_vol[-1]:.2f} ml, warp {warp_vol[-1]:.2f} ml; "
              f"ms/frame open {open_ms.mean():.1f}, warp {warp_ms.mean():.1f} ({warp.n_particles} particles)")
        assert len(open_iou) >= 10
        # Volumes (both containers) against the truth: 0.1–0.5 ml before the pour (the fills'
        # calibrations differ), up to 5.4–7.1 ml while the stream is in the air (the model's
        # stream runs a frame or two off the truth's).
        for err in (open_vol, warp_vol):
            assert err[0] < 1.0 and err.max() < 8.0, err
        gains.append(warp_iou.mean() - open_iou.mean())
        open_last.append(open_vol[-1])
        warp_last.append(warp_vol[-1])
    # Measured over five skins (0, 0.05, 0.1, 0.2, 0.3 h; bench/perturbed.py): the warp field's
    # IOU gain +0.042, -0.015, +0.009, +0.055, +0.050 (mean 0.028); the volume error at the last
    # frame open loop 1.75, 0.72, 0.59, 0.88, 0.47 ml, warp 0.54, 1.56, 0.71, 0.71, 0.15 ml (the
    # warp field's correction can move a few particles across the pan's rim). Asserted on the
    # means over SKINS: half the measured gain, and the old bounds on the last frame.
    assert np.mean(gains) > 0.014, gains
    assert np.mean(open_last) < 1.5 and np.mean(warp_last) < 2.5, (open_last, warp_last)


def test_checkpoint_continues_bit_for_bit(rec):
    a = _engine(rec)
    a.set_task(pb.Task(pour=pb.Task.PourToVolume(source="source", target="target", volume_ml=5.0)))
    for i in range(10):
        _frame(a, rec, i)
        a.control()
    buf = io.BytesIO()
    torch.save(a.state_dict(), buf)
    buf.seek(0)
    b = _engine(rec)
    b.load_state_dict(torch.load(buf, weights_only=True))
    for i in range(10, 20):
        _frame(a, rec, i)
        _frame(b, rec, i)
        assert a.control() == b.control()
    assert np.array_equal(a.positions(), b.positions()) and np.array_equal(a.speeds(), b.speeds())
    assert a.sim_time_s == b.sim_time_s and a.volumes() == b.volumes()
    other = SessionEngine.create(pb.SessionSpec(scene=rec.spec, tracking=pb.OPEN_LOOP))
    with pytest.raises(EngineError) as err:
        other.load_state_dict(a.state_dict())
    assert err.value.code == pb.Error.BAD_REQUEST


def test_frames_keep_the_remainder_and_cap_the_steps(rec):
    eng = _engine(rec, pb.OPEN_LOOP)
    dt = eng.dt
    assert eng.advance(0.0, {}).steps == 0
    r = eng.advance(2.4 * dt, {})
    assert r.steps == 2 and math.isclose(r.sim_time_s, 2 * dt)
    r = eng.advance(3.1 * dt, {})                     # 0.4 + 0.7 of a step carried: one more step
    assert r.steps == 1 and math.isclose(r.sim_time_s, 3 * dt) and r.sim_lag_s == 0
    r = eng.advance(20 * dt, {}, max_steps=8)
    assert r.steps == 8 and math.isclose(r.sim_lag_s, 9 * dt) and math.isclose(eng.sim_time_s, 20 * dt)
    # A pose given at a step time is where the object is after the frame.
    pose = np.array([0.08, 0.075, 0.0, 0.0, 0.0, math.sin(0.05), math.cos(0.05)])
    eng.advance(24 * dt, {"source": pose})
    np.testing.assert_allclose(eng._state.poses[0].numpy(), pose, atol=1e-6)
    for bad, code in [((23 * dt, {}), pb.Error.BAD_REQUEST), ((25 * dt, {"spoon": pose}), pb.Error.UNKNOWN_NAME),
                      ((25 * dt, {"source": pose[:6]}), pb.Error.BAD_REQUEST),
                      ((25 * dt, {"source": pose * 2}), pb.Error.BAD_REQUEST),
                      ((float("nan"), {}), pb.Error.BAD_REQUEST)]:
        with pytest.raises(EngineError) as err:
            eng.advance(*bad)
        assert err.value.code == code, bad
    assert eng.positions().shape == (eng.n_particles, 3) and eng.positions().dtype == np.float32
    assert eng.speeds().shape == (eng.n_particles,) and np.isfinite(eng.speeds()).all()
    eng.reset()
    assert eng.sim_time_s == 0 and eng.advance(0.0, {}).steps == 0


def test_overlay_colours_counts_and_iou():
    obs = np.zeros((4, 5), bool)
    mod = np.zeros((4, 5), bool)
    obs[0, :3] = True
    mod[0, 2:] = True
    mod[3, 4] = True
    ov = make_overlay(obs, mod)
    assert tuple(ov.image[0, 0]) == OBSERVED_RGB and tuple(ov.image[0, 2]) == OVERLAP_RGB
    assert tuple(ov.image[0, 4]) == MODEL_RGB and tuple(ov.image[2, 2]) == BACKGROUND_RGB
    assert (ov.observed_px, ov.model_px, ov.overlap_px) == (3, 4, 1)
    assert ov.iou == iou(torch.as_tensor(obs), torch.as_tensor(mod)) == 1 / 6


def test_correct_and_cameras(rec):
    eng = _engine(rec, pb.OPEN_LOOP)
    cam = rec.cameras[CAMERA]
    assert eng.camera_size(CAMERA) == (cam.height, cam.width) and eng.camera_size("nope") is None
    eng.advance(0.0, {})
    r = eng.correct(CAMERA, np.zeros((cam.height, cam.width), np.uint8))
    assert r.overlay.shape == (cam.height, cam.width, 3) and r.overlay.dtype == np.uint8
    assert (r.observed_px, r.model_px, r.iou) == (0, 0, 1.0)     # the liquid is hidden in the cup
    mask = np.zeros((cam.height, cam.width), bool)
    mask[100:110, 50:60] = True
    r = eng.correct(CAMERA, mask)
    assert (r.observed_px, r.model_px, r.iou) == (100, 0, 0.0)
    assert (r.overlay[mask] == OBSERVED_RGB).all() and (r.overlay[~mask] == BACKGROUND_RGB).all()
    eng.set_camera("side", K=cam.K, width=cam.width, height=cam.height)
    assert "side" in eng.camera_names
    for args, code in [(("nope", np.zeros((240, 320), bool)), pb.Error.UNKNOWN_NAME),
                       (("side", np.zeros((240, 320), bool)), pb.Error.BAD_REQUEST),      # no pose yet
                       ((CAMERA, np.zeros((10, 10), bool)), pb.Error.BAD_REQUEST)]:
        with pytest.raises(EngineError) as err:
            eng.correct(*args)
        assert err.value.code == code
    with pytest.raises(EngineError):
        eng.set_camera("side", pose=[0, 0, 0, 0, 0, 0, 2.0])
    meshes = eng.meshes()
    assert set(meshes) == set(eng.object_names) and meshes["source"][2] and not meshes["table"][2]
    assert meshes["source"][0].dtype == np.float32 and meshes["source"][1].dtype == np.uint32


def test_tasks_and_control(rec):
    eng = _engine(rec, pb.OPEN_LOOP)
    eng.advance(0.0, {})
    assert eng.control() is None
    held_ml = eng.volumes()["source"]
    assert abs(held_ml - 23.0) < 0.03 * 23.0
    pour = pb.Task.PourToVolume

    def task(**kw):
        args = dict(source="source", target="target", volume_ml=10.0, max_angle_rad=2.0, max_rate_rad_s=1.0)
        return pb.Task(pour=pour(**(args | kw)))
    cases = [(task(source="jug"), pb.Error.UNKNOWN_NAME), (task(volume_ml=held_ml + 1), pb.Error.INFEASIBLE),
             (task(volume_ml=-1), pb.Error.BAD_REQUEST), (task(target="source"), pb.Error.BAD_REQUEST),
             (task(target="table"), pb.Error.BAD_REQUEST), (task(max_angle_rad=4.0), pb.Error.BAD_REQUEST),
             (task(max_rate_rad_s=-1.0), pb.Error.BAD_REQUEST),
             (pb.Task(pour=task().pour, controller="lqr"), pb.Error.BAD_REQUEST),
             (pb.Task(pour=task(volume_ml=held_ml + 1).pour, controller="mpc"), pb.Error.INFEASIBLE)]
    for t, code in cases:
        with pytest.raises(EngineError) as err:
            eng.set_task(t)
        assert err.value.code == code, t
    eng.set_task(task())
    c = eng.control()
    assert c.object == "source" and c.controller == "pid" and not c.done
    assert 0.0 <= c.tilt_angle_rad <= 2.0 and 0 < c.tilt_rate_rad_s <= 1.0 and c.remaining_ml == pytest.approx(10.0)
    # The pour axis: horizontal, through the source's rim on the target's side (the pan is at
    # the origin, the cup at x ≈ +0.073 m: the rim point at x ≈ 0.033 m, 0.11 m above the cup's base).
    src = np.asarray(rec.spec.objects[0].initial_pose[:3])
    axis, point = np.asarray(c.axis_direction), np.asarray(c.axis_point_m)
    assert np.allclose(axis, [0, 0, 1], atol=0.05) and point[0] == pytest.approx(src[0] - 0.04, abs=0.005)
    assert point[1] == pytest.approx(src[1] + 0.11, abs=0.005)
    eng.set_task(pb.Task())
    assert eng.control() is None


@pytest.mark.parametrize("change,code", [
    (lambda s: setattr(s, "tracking", 99), pb.Error.BAD_REQUEST),       # no such tracking mode
    (lambda s: s.scene.fills[0].__setattr__("container", "table"), pb.Error.BAD_REQUEST),
    (lambda s: s.scene.fills[0].__setattr__("volume_ml", 5000.0), pb.Error.INFEASIBLE),
    (lambda s: s.fluid.__setattr__("lambda_v", -1.0), pb.Error.BAD_REQUEST),
    (lambda s: setattr(s, "correction_gain", -2.0), pb.Error.BAD_REQUEST),
    (lambda s: s.scene.objects[0].__setattr__("model", "teapot"), pb.Error.BAD_REQUEST),
])
def test_create_errors(rec, change, code):
    spec = pb.SessionSpec(scene=rec.spec)
    change(spec)
    with pytest.raises(EngineError) as err:
        SessionEngine.create(spec)
    assert err.value.code == code


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_cuda_without_cuda_is_infeasible(rec):
    with pytest.raises(EngineError) as err:
        SessionEngine.create(pb.SessionSpec(scene=rec.spec), device="cuda")
    assert err.value.code == pb.Error.INFEASIBLE and "CUDA" in str(err.value)


def test_a_fill_too_deep_for_the_solver_iterations_warns():
    # Liquid deeper than ~3 rest spacings per solver iteration boils at rest (test_physics);
    # a session told to run such a scene says so and how many iterations would hold it.
    import warnings

    from liquidtwin.generate.catalog import build_setup
    from liquidtwin.generate.generator import scene_spec
    from liquidtwin.session._build import build_scene
    setup = build_setup("pour_hold", np.random.default_rng(0), False, source="cup", fraction=0.9)
    spec = scene_spec(setup)
    src = next(o for o in spec.objects if o.name == "source")
    src.params.update({"radius": 0.02, "bottom_radius": 0.016, "height": 0.11})   # narrow: ~1k particles
    del spec.fills[:]
    spec.fills.add(container="source", fraction=0.9)
    for iterations, warns in ((4, True), (6, False)):
        spec.simulation.iterations = iterations
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            build_scene(pb.SessionSpec(scene=spec))
        said = [str(w.message) for w in caught if "solver iterations" in str(w.message)]
        assert bool(said) == warns, (iterations, said)
        if warns:
            assert "iterations >= 6" in said[0] and "'source'" in said[0]
