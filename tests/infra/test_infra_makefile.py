"""The Makefile: install order, idempotent venv stamp, entry points, .ci/run."""

import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def make(*args, cwd=ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "--no-print-directory", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=60)


def dry_run(*targets, cwd=ROOT) -> list[str]:
    run = make("-n", "-B", *targets, cwd=cwd)
    assert run.returncode == 0, run.stderr
    return run.stdout.splitlines()


def test_venv_installs_torch_first_and_alone_then_the_lock_then_the_packages():
    lines = dry_run("venv")
    assert lines[0] == "test -x .venv/bin/python || python3 -m venv .venv"
    assert lines[1] == ".venv/bin/python -m pip install --upgrade pip"
    assert lines[2] == ".venv/bin/python -m pip install torch==2.13.0"
    assert lines[3] == ".venv/bin/python -m pip install -r requirements.lock"
    # the C++ extension must build here (server/native_build.py): CI never tests the fallback
    assert lines[4] == ("LIQUIDTWIN_REQUIRE_NATIVE=1 .venv/bin/python -m pip install --no-build-isolation "
                        "-e ./proto -e ./server -e ./client -e ./viewer")
    assert lines[5].startswith("touch .venv/")


@pytest.mark.parametrize(
    "target, command",
    [
        ("test", "OMP_NUM_THREADS=1 .venv/bin/python -m pytest -q -n 2 --dist loadfile --durations=20 tests"),
        ("demo", ".venv/bin/liquidtwin demo"),
        ("bench", ".venv/bin/liquidtwin bench"),
        ("proto", ".venv/bin/python proto/generate.py"),
    ],
)
def test_entry_points(target, command):
    lines = [line.strip() for line in dry_run(target)]
    assert command in lines
    if target in ("test", "demo", "bench"):  # they build the venv first
        assert lines.index(".venv/bin/python -m pip install torch==2.13.0") < lines.index(command)


def test_clean_keeps_the_venv_but_drops_the_stamp():
    lines = dry_run("clean")
    assert any(".venv/.liquidtwin-installed" in line for line in lines)
    assert not any(w in (".venv", ".venv/") for line in lines for w in line.split())


def _sandbox(tmp_path: Path) -> Path:
    """A copy of the Makefile beside fake install inputs and an already-made stamp."""
    shutil.copy(ROOT / "Makefile", tmp_path / "Makefile")
    (tmp_path / "requirements.lock").write_text("numpy==1\n")
    for package in ("proto", "client", "viewer"):
        (tmp_path / package).mkdir()
        (tmp_path / package / "pyproject.toml").write_text("")
    (tmp_path / "server").mkdir()  # server/ without its build files yet
    stamp = tmp_path / ".venv" / ".liquidtwin-installed"
    stamp.parent.mkdir()
    stamp.touch()
    _age_inputs(tmp_path)
    return tmp_path


def _age_inputs(tmp_path: Path) -> None:
    """Make every file except the stamp an hour old."""
    old = time.time() - 3600
    for path in tmp_path.rglob("*"):
        if path.is_file() and path.name != ".liquidtwin-installed":
            os.utime(path, (old, old))


@pytest.mark.parametrize(
    "change",
    ["requirements.lock", "proto/pyproject.toml", "viewer/pyproject.toml",
     "server/pyproject.toml", "server/setup.py", "server/csrc/pbf.cpp"],
)
def test_venv_is_idempotent_and_reruns_when_an_install_input_changes(tmp_path, change):
    box = _sandbox(tmp_path)
    assert make("-q", "venv", cwd=box).returncode == 0, "fresh stamp must mean up to date"
    target = box / change
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text("changed\n")  # newer than the stamp (or newly created)
    assert make("-q", "venv", cwd=box).returncode == 1, f"{change} changed but venv is up to date"


def test_apt_step_is_a_no_op_without_packages():
    run = make("apt")
    assert run.returncode == 0 and run.stdout == ""


def test_ci_run_calls_make_test():
    ci = ROOT / ".ci" / "run"
    assert os.access(ci, os.X_OK)
    lines = ci.read_text().splitlines()
    assert lines[0] == "#!/usr/bin/env bash"
    assert "set -euo pipefail" in lines
    body = [line for line in lines if line and not line.startswith("#")]
    assert body[-1] == "make test"
    assert any(line.startswith("cd ") for line in body[:-1])
