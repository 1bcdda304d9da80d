"""docker-compose.yml and the Dockerfiles, checked by parsing (no docker engine here)."""

import json
import shlex
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
SERVICES = COMPOSE["services"]


def parse_dockerfile(path: Path) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) pairs of a Dockerfile, continuations joined, comments dropped."""
    steps, pending = [], ""
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not pending and (not line or line.startswith("#")):
            continue
        if pending and line.startswith("#"):
            continue
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        line, pending = pending + line, ""
        instruction, _, args = line.partition(" ")
        steps.append((instruction.upper(), " ".join(args.split())))
    assert not pending, f"{path}: dangling line continuation"
    return steps


def exec_form(args: str) -> list[str]:
    """The JSON array of an exec-form CMD/ENTRYPOINT."""
    value = json.loads(args)
    assert isinstance(value, list) and all(isinstance(v, str) for v in value)
    return value


def pip_installs(steps) -> list[list[str]]:
    """Argument lists of every `pip install` in RUN steps, in order."""
    out = []
    for instruction, args in steps:
        if instruction != "RUN":
            continue
        for command in args.split("&&"):
            words = shlex.split(command)
            if words[:2] == ["pip", "install"]:
                out.append(words[2:])
    return out


def dockerfile_of(service: str) -> Path:
    build = SERVICES[service]["build"]
    return ROOT / build["context"] / build["dockerfile"]


def test_services():
    assert set(SERVICES) == {"zenoh", "server", "viewer"}


def test_zenoh_router_listens_on_7447_without_multicast():
    zenoh = SERVICES["zenoh"]
    assert zenoh["image"].split(":")[0] == "eclipse/zenoh"
    assert ":" in zenoh["image"], "pin the router's version"
    command = zenoh["command"]
    listen = command[command.index("--listen") + 1]
    assert listen.startswith("tcp/") and listen.endswith(":7447")
    assert "--no-multicast-scouting" in command
    assert "7447:7447" in zenoh["ports"]


def test_server_connects_to_the_router():
    server = SERVICES["server"]
    assert server["build"] == {"context": ".", "dockerfile": "server/Dockerfile"}
    assert server["command"] == ["liquidtwin", "serve", "--connect", "tcp/zenoh:7447"]
    assert "zenoh" in server["depends_on"]


def test_viewer_serves_on_8080_from_mounted_recordings():
    viewer = SERVICES["viewer"]
    assert viewer["build"] == {"context": ".", "dockerfile": "viewer/Dockerfile"}
    assert "8080:8080" in viewer["ports"]
    command = viewer["command"]
    assert command[command.index("--host") + 1] == "0.0.0.0"
    assert command[command.index("--port") + 1] == "8080"
    mcap = command[command.index("--mcap") + 1]
    mounts = [v.split(":") for v in viewer["volumes"]]
    assert any(mcap.startswith(target + "/") and (ROOT / source).resolve().parent == ROOT
               for source, target, *_ in mounts)


@pytest.mark.parametrize("service", ["server", "viewer"])
def test_dockerfile_copies_exist_and_base_is_python(service):
    path = dockerfile_of(service)
    assert path.is_file()
    steps = parse_dockerfile(path)
    assert steps[0][0] == "FROM" and steps[0][1].startswith("python:3.11")
    for instruction, args in steps:
        if instruction == "COPY":
            *sources, _ = args.split()
            for source in sources:
                assert (ROOT / source).exists(), f"{path}: COPY source {source} missing"


def test_server_dockerfile_installs_cpu_torch_first_and_alone():
    steps = parse_dockerfile(dockerfile_of("server"))
    installs = pip_installs(steps)
    first = [w for w in installs[0] if not w.startswith("-") and "://" not in w]
    assert first == ["torch==2.13.0"]
    assert "--index-url" in installs[0] and installs[0][-1].endswith("/whl/cpu")
    assert ["-r", "requirements.lock"] in installs[1:]
    last = installs[-1]
    assert "--no-build-isolation" in last and {"./proto", "./server"} <= set(last)
    assert all("torch" not in " ".join(i) for i in installs[1:])
    cmd = [exec_form(a) for i, a in steps if i == "CMD"][-1]
    assert cmd == SERVICES["server"]["command"]


def test_viewer_dockerfile_has_no_torch_and_runs_the_viewer():
    path = dockerfile_of("viewer")
    steps = parse_dockerfile(path)
    assert "torch" not in path.read_text().replace("No torch", "")
    installs = pip_installs(steps)
    assert installs == [["-c", "requirements.lock", "./viewer"]]
    assert [exec_form(a) for i, a in steps if i == "ENTRYPOINT"] == [["liquidtwin-viewer"]]
    assert ("EXPOSE", "8080") in steps


def test_build_context_excludes_the_venv():
    ignored = (ROOT / ".dockerignore").read_text().split()
    assert ".venv" in ignored and ".git" in ignored


def test_parse_dockerfile_joins_continuations(tmp_path):
    f = tmp_path / "Dockerfile"
    f.write_text("# c\nFROM python:3.11-slim\nRUN a \\\n  # inner comment\n  && b\nCMD [\"x\"]\n")
    assert parse_dockerfile(f) == [("FROM", "python:3.11-slim"), ("RUN", "a && b"),
                                   ("CMD", '["x"]')]
