"""server/native_build.py: the C++ extension's flags per machine, and an install that goes on
without the extension when its build fails (unless LIQUIDTWIN_REQUIRE_NATIVE=1)."""

import importlib.util
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SERVER = ROOT / "server"
spec = importlib.util.spec_from_file_location("native_build", SERVER / "native_build.py")
native_build = importlib.util.module_from_spec(spec)
spec.loader.exec_module(native_build)


def test_x86_keeps_its_flags_and_other_machines_get_the_compilers_default_target():
    assert native_build.compile_args("x86_64") == ["-O3", "-fopenmp", "-march=x86-64-v2", "-DAT_PARALLEL_OPENMP=1"]
    assert native_build.compile_args("AMD64") == native_build.compile_args("x86_64")
    for machine in ("aarch64", "arm64", "ppc64le", "riscv64"):
        args = native_build.compile_args(machine)
        assert args == ["-O3", "-fopenmp", "-DAT_PARALLEL_OPENMP=1"], machine
        assert not any(a.startswith(("-march", "-mcpu", "-mtune")) for a in args)


def test_the_opt_in_and_opt_out_read_exactly_1():
    assert native_build.required({"LIQUIDTWIN_REQUIRE_NATIVE": "1"})
    assert not native_build.required({"LIQUIDTWIN_REQUIRE_NATIVE": "0"}) and not native_build.required({})
    assert native_build.skipped({"LIQUIDTWIN_NO_NATIVE": "1"}) and not native_build.skipped({})


def _wheel(tmp_path: Path, require: bool) -> subprocess.CompletedProcess:
    """Build a wheel of a copy of the server's build files (the package reduced to a stub) with a
    C++ compiler that answers like g++ but fails every compile."""
    src = tmp_path / "server"
    src.mkdir()
    for name in ("setup.py", "native_build.py", "pyproject.toml", "MANIFEST.in", "README.md"):
        shutil.copy(SERVER / name, src / name)
    shutil.copytree(SERVER / "csrc", src / "csrc")
    (src / "src" / "liquidtwin").mkdir(parents=True)
    (src / "src" / "liquidtwin" / "__init__.py").write_text("")
    cxx = tmp_path / "broken-c++"
    cxx.write_text('#!/bin/sh\nfor a in "$@"; do [ "$a" = "-c" ] && { echo "broken-c++: no" >&2; exit 1; }; done\n'
                   'exec c++ "$@"\n')
    cxx.chmod(0o755)
    env = {**os.environ, "CXX": str(cxx), "LIQUIDTWIN_REQUIRE_NATIVE": "1" if require else "0"}
    env.pop("LIQUIDTWIN_NO_NATIVE", None)
    return subprocess.run([sys.executable, "-m", "pip", "wheel", "-v", "--no-build-isolation", "--no-deps",
                           "-w", str(tmp_path / "dist"), str(src)],
                          capture_output=True, text=True, timeout=300, env=env)


@pytest.mark.skipif(shutil.which("c++") is None, reason="no C++ compiler")
def test_a_failed_build_installs_without_the_extension_and_says_why(tmp_path):
    run = _wheel(tmp_path, require=False)
    out = run.stdout + run.stderr
    assert run.returncode == 0, out[-6000:]
    assert "broken-c++: no" in out                      # the compiler really ran, and failed
    assert "liquidtwin._native did not build" in out and "pure-torch path" in out
    (wheel,) = (tmp_path / "dist").glob("liquidtwin-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "liquidtwin/__init__.py" in names
    assert not [n for n in names if "_native" in n]


@pytest.mark.skipif(shutil.which("c++") is None, reason="no C++ compiler")
def test_a_required_build_that_fails_fails_the_install(tmp_path):
    run = _wheel(tmp_path, require=True)
    assert run.returncode != 0
    assert "broken-c++: no" in run.stdout + run.stderr
    assert not list((tmp_path / "dist").glob("*.whl"))
