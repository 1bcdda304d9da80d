"""``liquidtwin serve`` says so when its sessions would run without the C++ kernels (an install
whose extension did not build: server/native_build.py)."""

from liquidtwin.service.cli import native_note
from liquidtwin.sim import fused


def test_a_cpu_server_without_the_kernels_warns_and_says_how_to_fix_it(monkeypatch):
    assert fused.available()                       # this install built them (make venv requires it)
    assert native_note("cpu") is None
    monkeypatch.setattr(fused, "_native", None)
    note = native_note("cpu")
    assert "not built" in note and "pure-torch" in note and "g++" in note
    assert native_note("cuda:0") is None           # the kernels are CPU kernels: nothing lost on a GPU
