"""Scene specs as files: protobuf JSON round trip, catalogue and user-mesh objects, clear errors."""

import hashlib

import numpy as np
import pytest
from liquidtwin_proto import liquidtwin_pb2 as pb

from liquidtwin.geometry import build
from liquidtwin.scenes.spec import (SpecError, impact_iterations, load_spec, save_spec, scene_objects, simulation_settings,
                                    solve_with)


def _spec(**fill) -> pb.SceneSpec:
    spec = pb.SceneSpec(name="my_pour")
    spec.objects.add(name="source", model="cup", container=True, initial_pose=[0.1, 0.2, 0, 0, 0, 0, 1])
    spec.objects[0].params["radius"] = 0.04
    spec.fills.add(container="source", **(fill or {"volume_ml": 150.0}))
    return spec


def test_json_round_trip_and_defaults(tmp_path):
    spec = _spec()
    save_spec(spec, tmp_path / "s.json")
    assert load_spec(tmp_path / "s.json") == spec
    assert '"volumeMl": 150.0' in (tmp_path / "s.json").read_text()
    sim = simulation_settings(spec)
    assert sim["h"] == 0.011 and sim["iterations"] == 4 and sim["spacing"] == pytest.approx(0.55 * 0.011)
    assert sim["reference_iterations"] is None                  # SPNets' cohesion, in full every iteration


def test_solving_with_more_iterations_keeps_the_liquid(tmp_path):
    """solve_with: the count changes, the cohesion stays what the stated count applied — and
    the session's model is built so (the pour it changes: tests/bench/test_pour_iterations.py)."""
    from liquidtwin.session._build import build_scene
    spec = _spec(volume_ml=20.0)
    assert solve_with(spec, 9) is spec
    sim = simulation_settings(spec)
    assert (sim["iterations"], sim["reference_iterations"]) == (9, 4)
    solve_with(spec, 2)                                        # again: still the liquid first stated
    assert (spec.simulation.iterations, spec.simulation.reference_iterations) == (2, 4)
    model = build_scene(pb.SessionSpec(scene=spec)).model
    assert (model.iterations, model.reference_iterations) == (2, 4)
    assert build_scene(pb.SessionSpec(scene=_spec(volume_ml=20.0))).model.reference_iterations is None
    for bad in (0, 2.5, True, "4"):
        with pytest.raises(ValueError, match="whole number"):
            solve_with(spec, bad)
    assert (spec.simulation.iterations, spec.simulation.reference_iterations) == (2, 4)     # unchanged


def test_impact_iterations_solve_the_longest_fall_between_the_containers():
    """A cup whose rim stands 0.35 m above a bowl's floor: liquid lands at sqrt(2 g 0.35)
    = 2.62 m/s, 3.61 rest spacings a 120 Hz step, so 11 iterations (3 per spacing); a
    non-container above them does not count, and the count never drops below the stated one."""
    import math
    spec = _spec()
    spec.objects.add(name="bowl", model="bowl", container=True, initial_pose=[0.1, 0.0, 0, 0, 0, 0, 1])
    objects = {n: m for n, m, _ in scene_objects(spec)}
    spec.objects[0].initial_pose[1] = 0.35 - objects["source"].rim_height
    speed = math.sqrt(2 * 9.81 * 0.35)
    expected = math.ceil(3 * speed / 120 / (0.55 * 0.011))
    assert expected == 11 and impact_iterations(spec) == expected
    spec.objects.add(name="shelf", model="bowl", container=False, initial_pose=[0.5, 0.9, 0, 0, 0, 0, 1])
    assert impact_iterations(spec) == expected
    spec.simulation.iterations = 14
    assert impact_iterations(spec) == 14
    spec.objects[0].initial_pose[1] = 0.0                       # side by side: the higher rim's fall
    spec.simulation.iterations = 0
    rim = max(objects["source"].rim_height, objects["bowl"].rim_height)
    assert impact_iterations(spec) == max(4, math.ceil(3 * math.sqrt(2 * 9.81 * rim) / 120 / (0.55 * 0.011)))


def test_catalogue_and_user_mesh_objects(tmp_path):
    cup = build("cup")
    path = tmp_path / "cup_mm.stl"
    mesh = cup.mesh.copy()
    mesh.apply_scale(1000.0)                                 # a file in millimetres
    mesh.export(path)
    spec = _spec()
    spec.objects.add(name="mine", model="mesh", mesh_uri="cup_mm.stl", container=True,
                     mesh_sha256=hashlib.sha256(path.read_bytes()).hexdigest(), params={"scale": 0.001})
    objs = scene_objects(spec, base_dir=tmp_path)
    assert [n for n, _, _ in objs] == ["source", "mine"]
    assert np.allclose(objs[0][2], [0.1, 0.2, 0, 0, 0, 0, 1])
    assert objs[1][1].capacity_ml == pytest.approx(cup.capacity_ml, rel=0.02)
    assert objs[0][1].capacity_ml > cup.capacity_ml          # radius 4 cm > default 3.75 cm
    spec.objects[1].mesh_sha256 = "0" * 64
    with pytest.raises(SpecError, match="SHA-256"):
        scene_objects(spec, base_dir=tmp_path)


@pytest.mark.parametrize("change, message", [
    (lambda s: setattr(s.objects[0], "model", "teapot"), "unknown model 'teapot'"),
    (lambda s: s.objects.add(name="source", model="bowl"), "unique"),
    (lambda s: s.fills.add(container="nowhere", volume_ml=1.0), "not a container"),
    (lambda s: s.objects[0].initial_pose.__setitem__(6, 3.0), "unit quaternion"),
    (lambda s: s.objects.add(name="m", model="mesh"), "needs mesh_uri"),
    (lambda s: setattr(s.fills[0], "fraction", 1.5), "fraction"),
])
def test_bad_specs_are_named(tmp_path, change, message):
    spec = _spec()
    change(spec)
    save_spec(spec, tmp_path / "bad.json")
    with pytest.raises(SpecError, match=message):
        load_spec(tmp_path / "bad.json")


def test_unreadable_files(tmp_path):
    (tmp_path / "a.json").write_text("{not json")
    with pytest.raises(SpecError, match="not a valid SceneSpec"):
        load_spec(tmp_path / "a.json")
    (tmp_path / "b.json").write_text('{"name": "x", "colour": "red"}')
    with pytest.raises(SpecError, match="not a valid SceneSpec"):
        load_spec(tmp_path / "b.json")
    with pytest.raises(SpecError, match="cannot read"):
        load_spec(tmp_path / "missing.json")


def test_a_generated_recordings_spec_builds_its_objects(tmp_path):
    from liquidtwin.generate import build_setup
    from liquidtwin.generate.generator import scene_spec
    setup = build_setup("pour_hold", np.random.default_rng(4), quick=True)
    spec = scene_spec(setup)
    save_spec(spec, tmp_path / "scene.json")
    objs = scene_objects(load_spec(tmp_path / "scene.json"))
    assert [n for n, _, _ in objs] == list(setup.names)
    for (name, model, pose), item in zip(objs, setup.objects):
        assert np.allclose(pose, setup.poses_at(0.0)[setup.index(name)])
        if item.model is not None:
            assert model.mesh.volume == pytest.approx(item.model.mesh.volume, rel=1e-9)
    table = objs[-1][1]
    assert table.mesh.bounds[1][1] == pytest.approx(0.0) and table.mesh.is_watertight
