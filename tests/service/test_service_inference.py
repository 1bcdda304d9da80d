"""Hidden-state inference served by RPC: a real ``liquidtwin serve`` process, a recording
streamed by ``liquidtwin-client stream --keep-session``, then ``infer_fill`` over Zenoh on
the session's own logged frames. The truth sidecar is read by this test only."""

from __future__ import annotations

import json

import numpy as np
import pytest
from liquidtwin_proto import Error
from test_stream_e2e import DATA, run_stream

from liquidtwin.generate.catalog import QUICK_FILL
from liquidtwin_client import Client, ServerError

RECORDING = DATA / "golden_pour_hold.mcap"          # quick cup (30 % of quick capacity) → pan


@pytest.fixture(scope="module")
def served(module_servers, tmp_path_factory):
    server = module_servers.start()
    run_stream(server, RECORDING, tmp_path_factory.mktemp("infer"), "infer", "--rate", "max",
               "--tracking", "open_loop", "--keep-session")
    with Client(server.endpoint) as client:
        yield server, client


def test_infer_fill_over_zenoh_equals_the_analysis_of_the_recording(served):
    # The session's logged frames, read back, are the recording's frames: the RPC's posterior
    # is the offline analysis's, number for number.
    from liquidtwin.inference import infer_fill
    from liquidtwin.recordings import read_recording
    _, client = served
    truth = json.loads(RECORDING.with_suffix(".truth.json").read_text())
    true_fraction = truth["setup"]["fraction"] * QUICK_FILL        # of the cup's capacity
    fractions = (3 * true_fraction, true_fraction)
    result = client.session("infer").infer_fill(fractions=fractions, tracking="open_loop", timeout=300)
    offline = infer_fill(read_recording(RECORDING, images=False), fractions=fractions, tracking="open_loop")
    assert list(result.probability) == list(offline.names)
    assert result.frames == offline.frames > 10
    assert np.allclose(list(result.log_likelihood.values()), offline.log_likelihood, rtol=0, atol=1e-6)
    assert np.allclose(result.over_time, offline.probability_over_time, atol=1e-9)
    assert result.best == offline.best
    assert abs(result.over_time[-1].sum() - 1.0) < 1e-9


def test_inference_errors_are_clear(served):
    server, client = served
    handle = client.session("infer")
    with pytest.raises(ServerError) as bad:
        handle.infer_fill(container="no_such_cup", timeout=120)
    assert bad.value.code == Error.UNKNOWN_NAME and "no_such_cup" in str(bad.value)
    with pytest.raises(ServerError) as nopipe:
        handle.infer_blockage(timeout=120)
    assert nopipe.value.code in (Error.BAD_REQUEST, Error.UNKNOWN_NAME) and "pipe" in str(nopipe.value)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        handle.infer_fill(fractions=(1.5,))
    # A session that has seen no frames yet has nothing to score.
    from liquidtwin.recordings import read_recording
    fresh = client.create_session(read_recording(RECORDING, images=False).spec, session_id="fresh")
    with pytest.raises(ServerError) as empty:
        fresh.infer_fill(timeout=120)
    assert empty.value.code == Error.INFEASIBLE and "no object poses" in str(empty.value)
    assert handle.status().state in ("running", "idle")               # the session carried on
