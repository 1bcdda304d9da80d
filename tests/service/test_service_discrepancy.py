"""Discrepancy discovery served by RPC: a real ``liquidtwin serve`` process, a recording
streamed by ``liquidtwin-client stream --keep-session``, then ``discrepancy`` over Zenoh on the
session's own logged frames (equal to the offline analysis of that log), and ``load_model``:
bad model files are refused clearly and harm nothing, a good one runs, survives a reset and a
server restart."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest
from liquidtwin_proto import Error, LoadModelRequest, SessionStatus, make_header
from test_stream_e2e import DATA, run_stream

from liquidtwin_client import Client, ServerError, model_text

RECORDING = DATA / "golden_pour_hold.mcap"          # quick cup (30 % of quick capacity) → pan
SESSION = "disc"
#: Small options: one observation candidate (re-draws the base rollout), one null realisation.
SMALL = dict(candidates=("time_offset",), null_runs=1, calibrate=False)


@pytest.fixture(scope="module")
def served(module_servers, tmp_path_factory):
    server = module_servers.start()
    run_stream(server, RECORDING, tmp_path_factory.mktemp("disc"), SESSION, "--rate", "max",
               "--tracking", "open_loop", "--keep-session")
    client = Client(server.endpoint)
    yield server, client
    client.close()


def test_discrepancy_over_zenoh_equals_the_offline_analysis_of_its_log(served):
    from liquidtwin.discrepancy import Options, analyse
    from liquidtwin.recordings import read_recording
    from liquidtwin.service.history import session_recording
    server, client = served
    handle = client.session(SESSION)
    spec = handle.status().spec
    cams = {n: (c.K, c.D, c.width, c.height, c.pose) for n, c in read_recording(RECORDING, images=False).cameras.items()}
    log = session_recording(server.state_dir / "sessions" / SESSION, spec, [o.name for o in spec.scene.objects], cams)
    box = {}

    def call():
        t0 = time.monotonic()
        try:
            box["result"] = handle.discrepancy(**SMALL, timeout=300)
        except Exception as exc:  # noqa: BLE001 - reported below
            box["error"] = exc
        box["wall_s"] = time.monotonic() - t0

    rpc = threading.Thread(target=call)
    rpc.start()                                       # the server analyses while this process does
    time.sleep(1.0)
    t0 = time.monotonic()
    assert handle.status().state in ("running", "idle")              # other RPCs are answered meanwhile
    status_s = time.monotonic() - t0
    t0 = time.monotonic()
    offline = analyse([log], None, options=Options(**SMALL))
    offline_s = time.monotonic() - t0
    rpc.join(300)
    assert "error" not in box, box.get("error")
    got = box["result"]
    print(f"\ndiscrepancy RPC {box['wall_s']:.1f} s, offline {offline_s:.1f} s, status meanwhile {status_s:.3f} s; "
          f"decision {got.decision}, gains {got.gains}")
    assert status_s < 5.0
    assert got.decision == offline["decision"] and got.model == offline["model"]
    assert [c["name"] for c in got.report["candidates"]] == [c["name"] for c in offline["candidates"]]
    for mine, ref in zip(got.report["candidates"], offline["candidates"]):
        assert mine["params"] == pytest.approx(ref["params"], abs=1e-12)
        assert mine["heldout_gain"]["mean"] == pytest.approx(ref["heldout_gain"]["mean"], abs=1e-9)
        assert mine["heldout_gain"]["ci95"] == pytest.approx(ref["heldout_gain"]["ci95"], abs=1e-9)
    assert got.report["baseline"]["heldout_loss"] == pytest.approx(offline["baseline"]["heldout_loss"], abs=1e-9)
    assert got.report["split"] == offline["split"] and got.report["split"]["held_out_frames"] > 3
    assert got.report["series"]["t"] == offline["_series"]["t"]
    assert got.report["options"]["candidates"] == ["time_offset"] and got.report["null"]["runs"] == 1


def test_discrepancy_errors_are_clear(served):
    server, client = served
    handle = client.session(SESSION)
    for kw, code, words in [(dict(candidates=("gravity",)), Error.BAD_REQUEST, "gravity"),
                            (dict(camera="nope"), Error.UNKNOWN_NAME, "nope"),
                            (dict(null_runs=1000), Error.BAD_REQUEST, "null_runs")]:
        with pytest.raises(ServerError) as err:
            handle.discrepancy(**kw, timeout=60)
        assert err.value.code == code and words in str(err.value), err.value
    with pytest.raises(ValueError, match="null_runs"):
        handle.discrepancy(null_runs=-1)
    from liquidtwin.recordings import read_recording
    fresh = client.create_session(read_recording(RECORDING, images=False).spec, session_id="disc-fresh")
    with pytest.raises(ServerError) as empty:
        fresh.discrepancy(**SMALL, timeout=60)
    assert empty.value.code == Error.INFEASIBLE and "no object poses" in str(empty.value)
    fresh.close()


def _load_raw(client, text: str) -> SessionStatus:
    key = client.keys.rpc("load_model", SESSION)
    return client.call(key, LoadModelRequest(header=make_header(SESSION), session_id=SESSION, model_json=text),
                       SessionStatus, 60)


def test_load_model_refuses_bad_files_and_runs_good_ones(served, module_servers, tmp_path):
    server, client = served
    handle = client.session(SESSION)
    st = handle.reset()
    p0, ml0 = st.particles, {v.name: v.ml for v in st.volumes}["source"]
    for text, words in [("garbage{", "not JSON"), ("", "empty"),
                        ('{"version": 1, "name": "gravity"}', "unknown model extension"),
                        ('{"version": 1, "name": "drag", "params": {"c": NaN}}', "finite"),
                        ('{"version": 1, "name": "drag", "params": {}}', "missing ['c']"),
                        ('{"version": 1, "name": "time_offset", "params": {"s": 3.0}}', "outside"),
                        ('{"version": 7, "name": "drag"}', "version")]:
        with pytest.raises(ServerError) as err:
            _load_raw(client, text)
        assert err.value.code == Error.BAD_REQUEST and words in str(err.value), (text, err.value)
        st = handle.status()                                           # the session carries on, model unchanged
        assert st.state in ("running", "idle") and st.model_json == ""
    with pytest.raises(ValueError, match="NaN or infinite"):
        model_text({"version": 1, "name": "drag", "params": {"c": float("nan")}})
    with pytest.raises(ValueError, match="does not exist"):
        handle.load_model(tmp_path / "missing.json")
    # A good model runs; reset keeps it; a fill error refills the source for the next episode.
    drag = {"version": 1, "name": "drag", "params": {"c": 2.0}, "base": {"lambda_v": 50.0}}
    assert json.loads(handle.load_model(drag).model_json) == drag
    path = tmp_path / "model.json"
    path.write_text(json.dumps({"version": 1, "name": "fill_error", "params": {"value": 0.25}, "base": {}}))
    st = handle.load_model(path)
    assert json.loads(st.model_json)["name"] == "fill_error"
    st = handle.reset()
    ml1 = {v.name: v.ml for v in st.volumes}["source"]
    print(f"\nfill_error 0.25: {p0} → {st.particles} particles, {ml0:.2f} → {ml1:.2f} ml in the source after reset")
    assert json.loads(st.model_json)["params"] == {"value": 0.25}
    assert 1.19 < ml1 / ml0 < 1.31 and st.particles > 1.1 * p0
    # A restarted server continues the session with its model.
    handle.load_model({"version": 1, "name": "camera_offset", "params": {"rx": 0.5, "ry": -0.5, "rz": 1.0}})
    time.sleep(1.5)                                                    # a checkpoint is written every second
    assert server.stop() == 0
    again = module_servers.start(state_dir=server.state_dir)
    with Client(again.endpoint) as c2:
        st = c2.session(SESSION).status()
    assert st.restored and json.loads(st.model_json)["params"] == {"rx": 0.5, "ry": -0.5, "rz": 1.0}
    assert np.isfinite(st.sim_time_s)
