"""Issue 7's service-level check: a headless robot world (examples/04_robot_world.py, a real
process) simulates the true world — jittered fluid, a hidden drag, noisy tracker poses and
noisy thermal masks — streams it to a real ``liquidtwin serve`` over Zenoh on 127.0.0.1,
applies the MPC task's controls and measures what truly landed in the pan (the world's own
count; the server never sees it)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "04_robot_world.py"
ASK_ML = 8.0
#: The issue's target: what truly lands in the pan is within the ask's tolerance. The quick
#: cup (323 particles, 0.07 ml each) lets its liquid go in slugs of up to ~3 ml a frame at
#: 30 fps, so the tolerance is ±3 ml. Measured at stop 41 (8 ml asked, hidden drag, seeds
#: 1–4): 8.54, 5.32, 7.13, 8.37 ml truly landed (the twin believed 10.9, 6.2, 7.2, 11.1). Before
#: stop 41 the world's liquid was half again as cohesive as its λ_c said (two more solver
#: iterations, each applying λ_c: generate/world.py) and seeds 1–4 landed 5.09, 2.00, 4.15,
#: 5.83 ml; this test then asserted only that more than 1 ml landed.
TOLERANCE_ML = 3.0


def test_robot_world_pours_through_the_server_closed_loop(servers, tmp_path):
    proc = servers.start()
    out = tmp_path / "robot.json"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    run = subprocess.run([sys.executable, str(EXAMPLE), "--connect", proc.endpoint, "--ml", str(ASK_ML),
                          "--controller", "mpc", "--effect", "drag", "--seed", "3", "--seconds", "5",
                          "--out", str(out)], capture_output=True, text=True, timeout=600, env=env)
    assert run.returncode == 0, run.stderr[-3000:] + proc.stderr()[-3000:]
    r = json.loads(out.read_text())
    print(r)
    assert r["effects"][0]["name"] == "drag" and r["switched_s"] is not None and r["upright"]
    assert r["max_tilt_deg"] > 60                      # it tilted until the liquid flowed
    assert abs(r["poured_ml"] - ASK_ML) <= TOLERANCE_ML, r    # the ask truly landed in the pan
    assert r["poured_ml"] + r["spilled_ml"] < 0.5 * r["source_before_ml"], r    # not the whole cup, as PD does
    assert r["server_achieved_ml"] >= 0.5 * ASK_ML, r   # it stopped on its twin's count, not early


def test_robot_world_catches_the_stream_through_the_server_closed_loop(servers, tmp_path):
    """--task catch: the world's source pours on its script (unknown to the server), the
    catcher starts 12-18 cm from where the scene's stream lands and moves at each Control's
    velocity. Measured on the worlds before stop 41 (seed 1, no hidden effect): 99.2 % truly caught, the catcher moving
    from 6.7 to −13.7 cm. With a hidden
    drag of 2.43 /m the same run caught 84.1 % while the twin counted 98.5 %, and a hidden
    wind across the catcher's rail (seed 2) 2.8 %: the twin's stream lands where the
    model says, not where the world's does (docs/service.md)."""
    proc = servers.start()
    out = tmp_path / "catch.json"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    run = subprocess.run([sys.executable, str(EXAMPLE), "--connect", proc.endpoint, "--task", "catch", "--seed", "1",
                          "--out", str(out)], capture_output=True, text=True, timeout=600, env=env)
    assert run.returncode == 0, run.stderr[-3000:] + proc.stderr()[-3000:]
    r = json.loads(out.read_text())
    print(r)
    assert r["effects"] == [] and r["left_in_source_ml"] < 0.05 * r["source_before_ml"]   # the pour happened
    assert abs(r["catcher_end_x_m"] - r["catcher_start_x_m"]) > 0.12   # it went to the stream …
    assert r["caught"] > 0.9, r                                          # … and truly caught it


def test_robot_world_catches_with_the_served_learned_policy(servers, tmp_path):
    """--task catch --controller policy: the server's learned catching policy (one network
    evaluation a frame on the tracked particles) instead of the MPC. Measured at stop 42 (seed
    1, no hidden effect): 98.9 % truly caught, the catcher moving from 6.7 to −3.3 cm."""
    proc = servers.start()
    out = tmp_path / "catch_policy.json"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    run = subprocess.run([sys.executable, str(EXAMPLE), "--connect", proc.endpoint, "--task", "catch", "--seed", "1",
                          "--controller", "policy", "--out", str(out)], capture_output=True, text=True, timeout=600,
                         env=env)
    assert run.returncode == 0, run.stderr[-3000:] + proc.stderr()[-3000:]
    r = json.loads(out.read_text())
    print(r)
    assert r["controller"] == "policy" and r["left_in_source_ml"] < 0.05 * r["source_before_ml"]
    assert abs(r["catcher_end_x_m"] - r["catcher_start_x_m"]) > 0.05   # it went towards the stream …
    assert r["caught"] > 0.9, r                                          # … and truly caught it
