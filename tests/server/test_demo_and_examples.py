"""``liquidtwin demo`` and the examples as real processes; the recording read back; volumes."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from liquidtwin.scenes import pour
from liquidtwin.sim import make_state

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
# One torch thread per child: the runs are small, and other jobs may hold the cores.
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}


def run(*args, timeout=300) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=ENV, cwd=ROOT)
    assert proc.returncode == 0, f"{args} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}"
    return proc


def read_mcap(path: Path) -> dict[str, list]:
    """{topic: [(log_time, schema name, decoded message), ...]} in log-time order."""
    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            out.setdefault(channel.topic, []).append((message.log_time, schema.name, decoded))
    return out


def cloud_points(cloud) -> np.ndarray:
    assert cloud.point_stride == 12
    assert [(f.name, f.offset) for f in cloud.fields] == [("x", 0), ("y", 4), ("z", 8)]
    return np.frombuffer(cloud.data, dtype="<f4").reshape(-1, 3)


@pytest.fixture(scope="module")
def scene():
    return pour.build_pour_scene(seconds=0.3)


# ------------------------------------------------------------------ command line


def test_help_of_every_command():
    top = run("-m", "liquidtwin.cli", "--help").stdout
    assert "demo" in top and "bench" in top
    demo = run("-m", "liquidtwin.cli", "demo", "--help").stdout
    for flag in ("--offline", "--recording", "--no-wait", "--out", "--seconds", "--particles-scale", "--backend"):
        assert flag in demo
    script = Path(sys.executable).with_name("liquidtwin")
    if script.exists():  # the console script of the editable install
        proc = subprocess.run([str(script), "--help"], capture_output=True, text=True, env=ENV,
                              timeout=120)
        assert proc.returncode == 0 and "demo" in proc.stdout


def test_demo_records_a_readable_mcap(tmp_path, scene):
    out = tmp_path / "rec" / "demo.mcap"
    proc = run("-m", "liquidtwin.cli", "demo", "--offline", "--seconds", "0.3", "--out", out)
    text = proc.stdout
    n = scene.state.x.shape[0]
    assert re.search(rf"particles\s+{n}\b", text), text
    assert re.search(r"steps\s+36\b", text), text
    for row in ("steps/s", "particle-steps/s", "cup (ml)", "bowl (ml)", "spilled (ml)"):
        assert row in text
    assert f"liquidtwin-viewer --mcap {out}" in text
    assert out.exists()

    topics = read_mcap(out)
    assert set(topics) == {"/particles", "/objects", "/volumes"}
    clouds = topics["/particles"]
    assert len(clouds) == 1 + math.ceil(36 / 4)  # t = 0, every 4th step, the last step
    times = [t for t, _, _ in clouds]
    assert times[0] == 0 and times[-1] == 300_000_000 and times == sorted(times)
    for _, schema, cloud in clouds:
        assert schema == "foxglove.PointCloud" and cloud.frame_id == "world"
        assert cloud.pose.orientation.w == 1.0
        x = cloud_points(cloud)
        assert x.shape == (n, 3) and np.isfinite(x).all()
        assert (x[:, 1] > -0.01).all() and (np.abs(x) < 0.5).all()  # above the floor, in the scene
    np.testing.assert_allclose(cloud_points(clouds[0][2]), scene.state.x.numpy(), atol=1e-6)

    for _, schema, tf in topics["/objects"]:
        assert schema == "foxglove.FrameTransforms"
        assert [t.child_frame_id for t in tf.transforms] == ["cup", "bowl", "floor"]
        assert all(t.parent_frame_id == "world" for t in tf.transforms)
    total = n * scene.model.particle_volume * 1e6
    for _, schema, vol in topics["/volumes"]:
        assert schema == "liquidtwin.v1.Volumes"
        ml = {c.name: c.ml for c in vol.containers}
        assert set(ml) == {"cup", "bowl", "spilled"}
        assert sum(ml.values()) == pytest.approx(total)
    assert {c.name: c.ml for c in topics["/volumes"][-1][2].containers}["cup"] == pytest.approx(total)


# ------------------------------------------------------------------ examples


#: Every example, and the option its test uses to keep it short (04 runs against a server, in
#: tests/service/test_robot_world.py).
SHORTENED_BY = {"01_step_and_gradient.py": "--steps", "02_pour_demo.py": "--steps",
                "03_generate_and_read.py": "--steps", "04_robot_world.py": "--seconds"}


def test_every_example_has_a_docstring_and_runs_in_the_test_suite():
    names = sorted(p.name for p in EXAMPLES.glob("[0-9][0-9]_*.py"))
    assert names == sorted(SHORTENED_BY), "add a test for a new example"
    for name in names:
        source = (EXAMPLES / name).read_text()
        assert source.startswith('"""'), f"{name} has no module docstring"
        assert SHORTENED_BY[name] in source


def test_example_01_step_and_gradient():
    text = run(EXAMPLES / "01_step_and_gradient.py", "--steps", "10").stdout
    grad = float(re.search(r"d loss / d lambda_v = (\S+)", text).group(1))
    assert math.isfinite(grad)
    assert grad < 0, text  # more viscosity, less spreading


def test_example_02_pour_demo(tmp_path):
    out = tmp_path / "pour.mcap"
    text = run(EXAMPLES / "02_pour_demo.py", "--steps", "8", "--out", out).stdout
    assert "8 steps" in text and re.search(r"cup 1\d\d\.\d ml", text), text
    clouds = read_mcap(out)["/particles"]
    assert len(clouds) == 3  # t = 0, step 4, step 8
    assert all(np.isfinite(cloud_points(c)).all() for _, _, c in clouds)


def test_example_03_generate_and_read(tmp_path):
    text = run(EXAMPLES / "03_generate_and_read.py", "--steps", "70", "--out", tmp_path / "g.mcap").stdout
    plain = float(re.search(r"plain: .* mean IOU (\S+)", text).group(1))
    off = float(re.search(r"camera_offset=2.0: .* mean IOU (\S+)", text).group(1))
    assert plain > 0.2 and off < 0.5 * plain, text       # a 2° calibration error costs most of the overlap
    assert (tmp_path / "g_plain.mcap").exists() and (tmp_path / "g_camera_offset.mcap").exists()


# ------------------------------------------------------------------ liquid_volumes


def test_liquid_volumes_counts_particles_in_each_container(scene):
    model, per_ml = scene.model, scene.model.particle_volume * 1e6
    poses = scene.state.poses
    cup_x = scene.state.x
    n = cup_x.shape[0]
    vol = pour.liquid_volumes(model, scene.state, scene.containers)
    assert vol == {"cup": pytest.approx(n * per_ml), "bowl": 0.0, "spilled": 0.0}
    assert 150 <= vol["cup"] <= 200

    # Hand-placed: 50 in the bowl's cavity, 7 on the floor outside, 3 inside the cup's wall.
    rng = np.random.default_rng(0)
    c = np.array([0.0, pour.BOWL_RADIUS + pour.WALL, 0.0])
    d = rng.normal(size=(50, 3))
    d[:, 1] = -np.abs(d[:, 1])
    d *= (0.9 * pour.BOWL_RADIUS * rng.random(50) ** (1 / 3) / np.linalg.norm(d, axis=1))[:, None]
    in_bowl = c + d
    on_floor = np.column_stack([np.linspace(-0.3, 0.3, 7), np.full(7, 0.005), np.full(7, 0.2)])
    wall_local = np.array([[pour.CUP_RADIUS + 0.5 * pour.WALL, 0.05, 0.0],
                           [0.0, 0.5 * pour.WALL, 0.0],
                           [0.0, 0.05, -(pour.CUP_RADIUS + 0.5 * pour.WALL)]])
    in_wall = pour._local_to_world(wall_local, poses[0].double().numpy())
    x = np.concatenate([cup_x.numpy(), in_bowl, on_floor, in_wall])
    state = make_state(x, poses=poses)
    vol = pour.liquid_volumes(model, state, scene.containers)
    assert vol["cup"] == pytest.approx(n * per_ml)
    assert vol["bowl"] == pytest.approx(50 * per_ml)
    assert vol["spilled"] == pytest.approx(10 * per_ml)


def test_liquid_volumes_follow_the_container_pose(scene):
    """The same cup-frame particles count as in the cup when the cup is tilted and moved."""
    traj = scene.trajectory
    local = pour.fill_cup(scene.model.spacing, pour.FILL_ML)
    for t in (0.0, 1.0, 2.3):
        pose = traj.cup_pose(t)
        assert traj.angle(t) >= 0
        ident = torch.tensor([0, 0, 0, 0, 0, 0, 1.0], dtype=torch.float64)
        poses = torch.stack([pose, ident, ident])
        x = pour._local_to_world(local, pose.numpy())
        vol = pour.liquid_volumes(scene.model, make_state(x, poses=poses), scene.containers)
        assert vol["cup"] == pytest.approx(len(local) * scene.model.particle_volume * 1e6)
        assert vol["spilled"] == 0.0


def test_pour_scene_trajectory_tilts_about_the_lip():
    traj = pour.Trajectory()
    assert traj.angle(0.0) == 0.0 and traj.angle(traj.duration + 0.1) == 0.0
    peak = traj.t_start + traj.t_tilt + 0.5 * traj.t_hold
    assert math.degrees(traj.angle(peak)) == pytest.approx(traj.tilt_deg)
    lip_local = np.array([[-(pour.CUP_RADIUS + pour.WALL), pour.CUP_HEIGHT, 0.0]])
    for t in (0.0, 1.0, peak):
        lip = pour._local_to_world(lip_local, traj.cup_pose(t).numpy())[0]
        np.testing.assert_allclose(lip, traj.lip, atol=1e-12)
