"""requirements.lock pins exactly what the venv holds, torch excepted, and satisfies
every package's declared dependencies; client and viewer never need torch."""

import re
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[2]
PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;#]+)$")


def lock() -> dict[str, Version]:
    pins = {}
    for line in (ROOT / "requirements.lock").read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        match = PIN.match(line)
        assert match, f"requirements.lock: {line!r} is not an exact 'name==version' pin"
        name = canonicalize_name(match.group(1))
        assert name not in pins, f"{name} pinned twice"
        pins[name] = Version(match.group(2))
    return pins


REQUIRED = ["numpy", "protobuf", "mcap", "mcap-protobuf-support", "foxglove-schemas-protobuf",
            "trimesh", "tqdm", "ninja", "matplotlib", "pytest", "pytest-xdist", "pyyaml", "viser",
            "grpcio-tools", "setuptools", "wheel"]


def test_lock_pins_the_required_packages_and_not_torch():
    pins = lock()
    missing = [n for n in REQUIRED if n not in pins]
    assert missing == []
    assert "torch" not in pins


def test_lock_matches_the_installed_versions():
    wrong = {}
    for name, version in lock().items():
        try:
            installed = Version(metadata.version(name))
        except metadata.PackageNotFoundError:
            wrong[name] = "not installed"
            continue
        if installed != version:
            wrong[name] = f"installed {installed}, pinned {version}"
    assert wrong == {}


def _requirements_satisfied(requirements, pins, who):
    """Each unconditional requirement that names a pinned package must accept its pin."""
    bad = []
    for text in requirements:
        req = Requirement(text)
        if req.marker is not None and not req.marker.evaluate({"extra": ""}):
            continue
        name = canonicalize_name(req.name)
        if name in pins and not req.specifier.contains(pins[name], prereleases=True):
            bad.append(f"{who} wants {text}, lock has {pins[name]}")
    return bad


def test_lock_is_consistent_with_itself_and_torch():
    pins = lock()
    bad = []
    for name in [*pins, "torch"]:
        try:
            requires = metadata.requires(name) or []
        except metadata.PackageNotFoundError:
            continue
        bad += _requirements_satisfied(requires, pins, name)
    assert bad == []


@pytest.mark.parametrize("package", ["proto", "client", "viewer"])
def test_lock_satisfies_our_packages(package):
    project = tomllib.loads((ROOT / package / "pyproject.toml").read_text())["project"]
    assert _requirements_satisfied(project["dependencies"], lock(), package) == []
    for dep in project["dependencies"]:
        assert canonicalize_name(Requirement(dep).name) in lock() or \
            Requirement(dep).name.startswith("liquidtwin"), f"{package}: {dep} is not pinned"


def _closure(root: str) -> set[str]:
    """Names of every distribution ``root`` needs, transitively, from installed metadata."""
    seen, todo = set(), [canonicalize_name(root)]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        for text in metadata.requires(name) or []:
            req = Requirement(text)
            if req.marker is None or req.marker.evaluate({"extra": ""}):
                todo.append(canonicalize_name(req.name))
    return seen


@pytest.mark.parametrize("dist", ["liquidtwin-proto", "liquidtwin-client", "liquidtwin-viewer"])
def test_robot_side_packages_do_not_need_torch(dist):
    assert "torch" not in _closure(dist)


def test_robot_side_packages_import_without_torch():
    code = ("import sys; sys.modules['torch'] = None\n"
            "import liquidtwin_proto, liquidtwin_client, liquidtwin_client.cli\n"
            "import liquidtwin_viewer, liquidtwin_viewer.app, liquidtwin_viewer.cli\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0, run.stderr
