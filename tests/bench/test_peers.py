"""Peer benchmark (bench/peers/): the taichi PBF peer is a bench-only extra.

CI installs only the main requirements, so these tests must hold both ways:
with taichi installed they run the peer for real (timing fields, neighbour
count, a short dam break that settles); without it they check that the
"not installed" path is a clear, catchable ImportError.  The forced-absent
test runs in every environment.
"""

import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.peers import PEER_REQUIREMENTS, PeerNotInstalled, run_peer, try_run_peer  # noqa: E402
from bench.peers import taichi_pbf  # noqa: E402  (must import without taichi)

HAVE_TAICHI = importlib.util.find_spec("taichi") is not None
N = 500


def _cli(args, block_taichi=False):
    code = "import sys\n"
    if block_taichi:
        code += "sys.modules['taichi'] = None\n"
    code += "from bench.peers.taichi_pbf import main\nsys.exit(main(sys.argv[1:]))\n"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-c", code, *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)


def test_taichi_peer_runs_or_says_it_is_missing():
    if HAVE_TAICHI:
        import taichi

        res = taichi_pbf.run(N, steps=3, warmup=1)
        assert res["peer"] == "taichi"
        assert res["version"] == ".".join(map(str, taichi.__version__))
        assert (res["particles"], res["steps"], res["iterations"]) == (N, 3, 3)
        assert math.isfinite(res["particle_steps_per_s"]) and res["particle_steps_per_s"] > 0
        # 500 particles are mostly free surface; the bulk must see the ~30 of a 0.5 h lattice
        assert 12 <= res["mean_neighbors"] <= 45
        assert 24 <= res["mean_neighbors_bulk"] <= 45
        assert res["neighbor_overflow"] == 0
    else:
        with pytest.raises(PeerNotInstalled) as err:
            taichi_pbf.run(N, steps=3, warmup=1)
        assert PEER_REQUIREMENTS in str(err.value)
        assert try_run_peer("taichi", N, steps=3, warmup=1) is None
        assert taichi_pbf.available() is False


def test_taichi_peer_dam_break_settles_or_says_it_is_missing():
    if HAVE_TAICHI:
        v = taichi_pbf.validate(N, steps=600)  # 10 s of simulated time
        assert v["finite"] and v["in_box"]
        assert v["neighbor_overflow"] == 0
        assert v["interior_particles"] > 0
        assert 0.95 <= v["interior_density_ratio"] <= 1.05  # incompressible to a few %
        assert 28 <= v["interior_neighbors"] <= 40
        assert v["mean_speed"] < 0.1 * v["free_fall_speed"]  # settled, not exploded
        depth = v["settled_depth_expected"]
        assert abs(v["surface_height"] - depth) < 0.25 * depth  # the column spread out
    else:
        with pytest.raises(ImportError, match="taichi"):
            taichi_pbf.validate(N, steps=10)


def test_missing_taichi_is_a_clear_catchable_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "taichi", None)  # as if the extra were not installed
    with pytest.raises(PeerNotInstalled) as err:
        run_peer("taichi", N, steps=3, warmup=1)
    assert isinstance(err.value, ImportError)
    assert err.value.name == "taichi" and err.value.peer == "taichi"
    assert f"pip install -r {PEER_REQUIREMENTS}" in str(err.value)
    assert try_run_peer("taichi", N) is None
    assert taichi_pbf.available() is False
    with pytest.raises(ValueError, match="unknown peer"):
        run_peer("no-such-peer", N)


def test_cli_prints_json_or_exits_2_with_message():
    args = ["--particles", str(N), "--steps", "2", "--warmup", "1"]
    if HAVE_TAICHI:
        proc = _cli(args)
        assert proc.returncode == 0, proc.stderr
        lines = proc.stdout.strip().splitlines()
        assert len(lines) == 1  # stdout is pure JSON; taichi's banner goes to stderr
        assert json.loads(lines[0])["particles"] == N
    blocked = _cli(args, block_taichi=True)
    assert blocked.returncode == 2
    assert blocked.stdout == ""
    assert "not installed" in blocked.stderr and PEER_REQUIREMENTS in blocked.stderr
