"""End to end: two sessions of different scenes (golden pour_dump and pour_hold) streamed at
once by two ``liquidtwin-client stream`` processes into one ``liquidtwin serve`` give the
same results as each streamed alone (lockstep, ``--rate max``, so every frame sees the same
inputs in both runs).
"""

from __future__ import annotations

import json
import os
import subprocess

import numpy as np
import pytest
from test_stream_e2e import DATA, by_stamp, run_stream, stream_cmd

from liquidtwin_client import decode_particles, read_results

RECORDINGS = {"dump": DATA / "golden_pour_dump.mcap", "hold": DATA / "golden_pour_hold.mcap"}
#: Positions of a session run beside another vs alone, m. The engine runs each session's
#: steps on its own thread with its own state, so the results are expected bit for bit.
POSITION_TOL_M = 1e-6


def _together(server, tmp):
    """Both recordings streamed at once; {name: run} like run_stream's."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    procs = {name: subprocess.Popen(stream_cmd(server, rec, tmp, f"{name}-together",
                                               "--rate", "max", "--tracking", "warp_field"),
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    env=env)
             for name, rec in RECORDINGS.items()}
    out = {}
    for name, proc in procs.items():
        stdout, stderr = proc.communicate(timeout=300)
        if proc.returncode != 0:
            pytest.fail(f"{name}: exit {proc.returncode}\n{stderr[-3000:]}\nserver log:\n"
                        f"{server.stderr()[-3000:]}")
        out[name] = {"summary": json.loads((tmp / f"{name}-together.json").read_text()),
                     "results": read_results(tmp / f"{name}-together.mcap"), "stdout": stdout}
    return out


@pytest.fixture(scope="module")
def runs(module_servers, tmp_path_factory):
    """Each recording streamed alone, then both at once, through one server."""
    tmp = tmp_path_factory.mktemp("sessions")
    server = module_servers.start()
    alone = {name: run_stream(server, rec, tmp, f"{name}-alone", "--rate", "max",
                              "--tracking", "warp_field")
             for name, rec in RECORDINGS.items()}
    return alone, _together(server, tmp)


def test_concurrent_sessions_answer_every_frame(runs):
    alone, together = runs
    for name, rec in RECORDINGS.items():
        n = len(np.load(rec.with_suffix(".truth.npz"))["pose_stamps_ns"])
        for run in (alone[name], together[name]):
            s = run["summary"]
            assert (s["frames_sent"], s["frames_answered"], s["frames_timed_out"]) == (n, n, 0)
            assert len(run["results"]["particles"]) == n
    # "together" really overlapped: each session answered frames while the other streamed
    span = {n: (r["results"]["particles"][0].log_time_ns, r["results"]["particles"][-1].log_time_ns)
            for n, r in together.items()}
    assert span["dump"][0] < span["hold"][1] and span["hold"][0] < span["dump"][1], span
    # the two scenes really differ (else "same as alone" would not show outputs crossing)
    assert len(alone["dump"]["results"]["particles"]) != len(alone["hold"]["results"]["particles"])


def test_each_session_gives_the_same_results_as_alone(runs):
    alone, together = runs
    for name in RECORDINGS:
        a, t = alone[name]["results"], together[name]["results"]
        pa, pt = by_stamp(a["particles"]), by_stamp(t["particles"])
        assert pa.keys() == pt.keys()
        worst = 0.0
        for stamp in pa:
            xa, va = decode_particles(pa[stamp])
            xt, vt = decode_particles(pt[stamp])
            assert xa.shape == xt.shape
            worst = max(worst, float(np.abs(xa - xt).max()))
        print(f"{name}: max |position alone - together| over all frames {worst:.3g} m")
        assert worst <= POSITION_TOL_M
        va, vt = by_stamp(a["volumes"]), by_stamp(t["volumes"])
        for stamp in va:
            assert [(c.name, round(c.ml, 6)) for c in va[stamp].containers] == \
                [(c.name, round(c.ml, 6)) for c in vt[stamp].containers]
        ia = [m.message.iou for m in a["metrics"]]
        it = [m.message.iou for m in t["metrics"]]
        np.testing.assert_allclose(ia, it, atol=1e-6)
        sa, st = alone[name]["summary"], together[name]["summary"]
        assert sa["final_volumes_ml"].keys() == st["final_volumes_ml"].keys()
        print(f"{name}: latency p50/p99 alone {sa['latency_ms_p50']:.1f}/"
              f"{sa['latency_ms_p99']:.1f} ms, together {st['latency_ms_p50']:.1f}/"
              f"{st['latency_ms_p99']:.1f} ms; mean IOU {sa['mean_iou']:.3f}")
