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


def _router_endpoint() -> tuple[str, int]:
    """(service name, port) a container reaches the router at."""
    command = SERVICES["zenoh"]["command"]
    port = int(command[command.index("--listen") + 1].rsplit(":", 1)[1])
    return "zenoh", port


def _connect_target(endpoint: str) -> tuple[str, int]:
    assert endpoint.startswith("tcp/"), endpoint
    host, port = endpoint[len("tcp/"):].rsplit(":", 1)
    return host, int(port)


def test_server_command_is_a_valid_serve_invocation_against_the_router():
    from liquidtwin.cli import build_parser

    server = SERVICES["server"]
    assert server["build"] == {"context": ".", "dockerfile": "server/Dockerfile"}
    command = server["command"]
    assert command[0] == "liquidtwin"
    args = build_parser().parse_args(command[1:])  # exits (fails the test) on a bad flag
    assert args.command == "serve"
    assert [_connect_target(e) for e in args.connect] == [_router_endpoint()]
    assert "zenoh" in server["depends_on"]
    # the state directory is a volume, so logs and checkpoints survive the container
    state = command[command.index("--state-dir") + 1]
    assert any(v.split(":")[1] == state for v in server["volumes"])
    assert state.split(":")[0] not in ("", ".")


def test_viewer_command_is_a_valid_live_invocation_with_its_port_published():
    from liquidtwin_viewer.cli import build_parser

    viewer = SERVICES["viewer"]
    assert viewer["build"] == {"context": ".", "dockerfile": "viewer/Dockerfile"}
    args = build_parser().parse_args(viewer["command"])
    assert args.mcap is None, "the compose viewer shows live data"
    assert _connect_target(args.connect) == _router_endpoint()
    assert args.host == "0.0.0.0"
    published = {int(p.split(":")[1]) for p in viewer["ports"]}
    assert args.port in published
    # the image's default command is the same live invocation
    steps = parse_dockerfile(dockerfile_of("viewer"))
    assert [exec_form(a) for i, a in steps if i == "CMD"][-1] == viewer["command"]
    assert ("EXPOSE", str(args.port)) in steps


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
    assert installs == [["-c", "requirements.lock", "./proto", "./viewer"]]
    assert [exec_form(a) for i, a in steps if i == "ENTRYPOINT"] == [["liquidtwin-viewer"]]


def test_build_context_excludes_the_venv():
    ignored = (ROOT / ".dockerignore").read_text().split()
    assert ".venv" in ignored and ".git" in ignored


def test_parse_dockerfile_joins_continuations(tmp_path):
    f = tmp_path / "Dockerfile"
    f.write_text("# c\nFROM python:3.11-slim\nRUN a \\\n  # inner comment\n  && b\nCMD [\"x\"]\n")
    assert parse_dockerfile(f) == [("FROM", "python:3.11-slim"), ("RUN", "a && b"),
                                   ("CMD", '["x"]')]
