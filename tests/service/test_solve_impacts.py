"""``liquidtwin serve --solve-impacts``: a session whose SceneSpec states fewer solver
iterations than liquid falling between its containers needs gets that count, for the same
liquid; its engine, its status and its saved spec (what a restart restores) all say so.
A real server on loopback with real engines."""

from __future__ import annotations

import math

import pytest
from liquidtwin.scenes.spec import scene_objects
from liquidtwin.service import ServeConfig, Server
from liquidtwin.service.checkpoint import read_spec, sessions_root
from liquidtwin.service.cli import config_from_args
from liquidtwin.session import SessionEngine
from liquidtwin_proto import liquidtwin_pb2 as pb
from zraw import Peer, free_port, header, pour_spec

RAISE = 0.2                     # m: the cup stands this high above the bowl


def _raised_pour(iterations: int = 2) -> pb.SessionSpec:
    spec = pour_spec()                                    # cup beside a bowl, h 0.02, dt 1/60, 2 iterations
    spec.scene.objects[0].initial_pose[1] = RAISE
    spec.scene.simulation.iterations = iterations
    return spec


def _need(spec: pb.SessionSpec) -> int:
    """The rule written out: the cup's rim above the bowl's floor, free fall, 3 iterations per
    rest spacing (0.55 h) moved in a step."""
    rim = {n: m.rim_height for n, m, _ in scene_objects(spec.scene)}["src"]
    speed = math.sqrt(2 * 9.81 * (RAISE + rim))
    return math.ceil(3 * speed * spec.scene.simulation.dt / (0.55 * spec.scene.simulation.h))


@pytest.fixture
def served(tmp_path):
    engines = {}

    def factory(spec, device="cpu"):
        engines[len(engines)] = engine = SessionEngine.create(spec, device=device)
        return engine

    def start(solve_impacts: bool, state: str):
        cfg = ServeConfig(listen=[f"tcp/127.0.0.1:{free_port()}"], state_dir=tmp_path / state,
                          solve_impacts=solve_impacts)
        server = Server(cfg, engine_factory=factory)
        server.start()
        started.append((server, Peer(cfg.listen[0])))
        return cfg, started[-1][1]

    started = []
    yield start, engines
    for server, peer in started:
        peer.close()
        server.stop()


def test_a_session_below_its_falls_count_solves_it_for_the_same_liquid(served):
    start, engines = served
    cfg, peer = start(True, "on")
    need = _need(_raised_pour())
    assert need >= 8                                      # far above the 2 it states
    status = peer.create("raised", _raised_pour())
    sim = status.spec.scene.simulation
    assert (sim.iterations, sim.reference_iterations) == (need, 2)
    model = engines[0]._scene.model
    assert (model.iterations, model.reference_iterations) == (need, 2)
    saved = read_spec(sessions_root(cfg.state_dir) / "raised").scene.simulation
    assert (saved.iterations, saved.reference_iterations) == (need, 2)
    # a spec that states enough is left as it is
    status = peer.create("enough", _raised_pour(iterations=need + 3))
    assert (status.spec.scene.simulation.iterations, status.spec.scene.simulation.reference_iterations) == (need + 3, 0)
    # a scene that cannot be built still gets the engine's own clear error
    bad = _raised_pour()
    bad.scene.objects[1].model = "no_such_model"
    req = pb.CreateSessionRequest(header=header(), session_id="bad", spec=bad)
    err = peer.error("rpc/create_session", req.SerializeToString())
    assert err.code == pb.Error.BAD_REQUEST and "no_such_model" in err.message, err


def test_without_the_option_a_session_solves_what_it_states(served):
    start, engines = served
    _, peer = start(False, "off")
    status = peer.create("raised", _raised_pour())
    assert (status.spec.scene.simulation.iterations, status.spec.scene.simulation.reference_iterations) == (2, 0)
    assert engines[0]._scene.model.iterations == 2


def test_the_command_line_sets_it():
    import argparse
    from liquidtwin.service.cli import add_serve_parser
    p = argparse.ArgumentParser()
    add_serve_parser(p)
    assert config_from_args(p.parse_args(["--solve-impacts"])).solve_impacts
    assert not config_from_args(p.parse_args([])).solve_impacts
