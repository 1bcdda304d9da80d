"""``liquidtwin demo``: the product on one machine — server, viewer and a robot client.

Starts ``liquidtwin serve`` on the embedded default (a Zenoh peer on tcp/127.0.0.1:7447),
``liquidtwin-viewer`` connected to it, then streams a bundled generated pour through
``liquidtwin-client stream`` (the headless robot client) and prints its summary table and
the viewer's address. The viewer stays up until Ctrl-C unless ``--no-wait``. The three
programs run as separate processes exactly as a lab would run them; this module only
starts, watches and stops them (the server package never imports the client or viewer).

``liquidtwin demo --offline`` is the earlier, service-free demo: simulate a cup pouring
into a bowl and record it to MCAP (``liquidtwin.cli.run_demo``).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

#: The bundled recording: a generated partial pour (``liquidtwin generate --scene
#: pour_partial --seed 3``), shipped with the package.
DEMO_RECORDING = Path(__file__).resolve().parent / "data" / "demo_pour.mcap"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
_READY_S = 120.0  # longest wait for the server / viewer to say they are up


def configure(p: argparse.ArgumentParser) -> None:
    """Arguments of ``liquidtwin demo`` (product demo; ``--offline`` for the old one)."""
    p.add_argument("--offline", action="store_true",
                   help="run the service-free demo instead: simulate a cup→bowl pour and record it")
    p.add_argument("--recording", type=Path, default=DEMO_RECORDING, metavar="REC.mcap",
                   help="recording to stream through the server (default: the bundled pour)")
    p.add_argument("--endpoint", default=DEFAULT_ENDPOINT, metavar="EP",
                   help="Zenoh endpoint the server listens on (default: %(default)s)")
    p.add_argument("--port", type=int, default=8080, help="viewer port (default: %(default)s)")
    p.add_argument("--rate", choices=("realtime", "max"), default="max",
                   help="replay pace: 'max' answers every frame (lockstep, slower than real time on "
                        "a 2-core CPU: the bundled pour simulates 2k particles at dt = 1/120 s), "
                        "'realtime' paces by the recorded stamps and the server drops frames it "
                        "cannot keep up with (default: %(default)s)")
    p.add_argument("--tracking", choices=("warp_field", "open_loop"), default="warp_field",
                   help="closed-loop tracker of the demo session (default: %(default)s)")
    p.add_argument("--state-dir", type=Path, default=Path("out/demo-state"), metavar="DIR",
                   help="server state (logs, checkpoints) (default: %(default)s)")
    p.add_argument("--no-wait", action="store_true",
                   help="stop everything after the stream instead of keeping the viewer up")
    p.add_argument("--no-viewer", action="store_true", help="do not start the viewer")
    # the offline demo's options
    p.add_argument("--out", type=Path, default=None, metavar="PATH",
                   help="MCAP to write: the client's results (default out/demo-results.mcap), or "
                        "with --offline the simulated pour (default out/demo.mcap)")
    p.add_argument("--seconds", type=float, default=None, metavar="S",
                   help="--offline: simulated time in s (default: the whole pour, about 5.2 s)")
    p.add_argument("--particles-scale", type=float, default=1.0, metavar="F",
                   help="--offline: multiply the particle count by F at the same liquid volume")
    p.add_argument("--backend", choices=("auto", "torch", "fused"), default="auto",
                   help="--offline: pair-sum back end (default: auto)")
    p.add_argument("--every", type=int, default=4, metavar="K",
                   help="--offline: record every K-th step (default: %(default)s)")
    p.add_argument("--threads", type=int, default=1, metavar="N",
                   help="--offline: torch CPU threads (default: 1)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")


def run(args: argparse.Namespace) -> int:
    """``liquidtwin demo``: the product demo, or the offline pour with ``--offline``."""
    if args.offline:
        from .cli import run_demo
        if args.out is None:
            args.out = Path("out/demo.mcap")
        return run_demo(args)
    return _run_service_demo(args)


def _run_service_demo(args: argparse.Namespace) -> int:
    if not args.recording.is_file():
        print(f"liquidtwin demo: recording {args.recording} not found", file=sys.stderr)
        return 2
    host, port = _host_port(args.endpoint)
    for what, (h, p) in (("the server", (host, port)),) + (
            () if args.no_viewer else (("the viewer", ("127.0.0.1", args.port)),)):
        if _in_use(h, p):
            print(f"liquidtwin demo: {h}:{p} is already in use, so {what} cannot start there — "
                  f"is another liquidtwin running? Pick another with "
                  f"{'--endpoint' if what == 'the server' else '--port'}.", file=sys.stderr)
            return 2
    out = args.out or Path("out/demo-results.mcap")
    out.parent.mkdir(parents=True, exist_ok=True)
    args.state_dir.mkdir(parents=True, exist_ok=True)
    logs = out.parent
    procs: list[subprocess.Popen] = []
    try:
        server = _start([_tool("liquidtwin"), "serve", "--listen", args.endpoint,
                         "--state-dir", str(args.state_dir)], logs / "demo-server.log", procs)
        _wait_for(server, r"ready on", "liquidtwin serve", logs / "demo-server.log")
        url = None
        if not args.no_viewer:
            viewer = _start([_tool("liquidtwin-viewer"), "--connect", args.endpoint,
                             "--port", str(args.port)], logs / "demo-viewer.log", procs)
            line = _wait_for(viewer, r"https?://\S+", "liquidtwin-viewer", logs / "demo-viewer.log")
            url = re.search(r"https?://\S+", line).group(0)
            print(f"liquidtwin demo: viewer at {url} (open it to watch the pour live)", flush=True)
        stream = [_tool("liquidtwin-client"), "stream", str(args.recording), "--session", "demo",
                  "--rate", args.rate, "--tracking", args.tracking, "--connect", args.endpoint,
                  "--out", str(out)]
        code = subprocess.call(stream)
        if code != 0:
            print(f"liquidtwin demo: the client failed (exit {code}); server log: "
                  f"{logs / 'demo-server.log'}", file=sys.stderr)
            return code
        print(f"liquidtwin demo: results in {out}; server state and logs in {args.state_dir}")
        if url and not args.no_wait:
            print(f"liquidtwin demo: the viewer stays up at {url} — press Ctrl-C to stop.", flush=True)
            _wait_for_interrupt(procs)
        return 0
    except _Failed as exc:
        print(f"liquidtwin demo: {exc}", file=sys.stderr)
        return 1
    finally:
        _stop(procs)


class _Failed(RuntimeError):
    pass


def _tool(name: str) -> str:
    """A console script of this environment (beside the running Python), else from PATH."""
    local = Path(sys.executable).parent / name
    found = str(local) if local.is_file() else shutil.which(name)
    if found is None:
        raise _Failed(f"`{name}` is not installed in this environment (run `make venv`)")
    return found


def _host_port(endpoint: str) -> tuple[str, int]:
    m = re.fullmatch(r"tcp/([^:]+|\[[^\]]+\]):(\d+)", endpoint)
    if not m:
        raise SystemExit(f"liquidtwin demo: --endpoint must look like tcp/HOST:PORT, got {endpoint!r}")
    return m.group(1).strip("[]"), int(m.group(2))


def _in_use(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return True
    return False


def _start(cmd: list[str], log: Path, procs: list) -> subprocess.Popen:
    """Start ``cmd``; its stderr goes to ``log``, its stdout is read by :func:`_wait_for`."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=open(log, "w"), text=True,
                            start_new_session=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    procs.append(proc)
    return proc


def _wait_for(proc: subprocess.Popen, pattern: str, name: str, log: Path) -> str:
    """The first stdout line of ``proc`` matching ``pattern``; later lines are drained."""
    found: list[str] = []
    event = threading.Event()

    def pump():
        for line in proc.stdout:
            if not event.is_set() and re.search(pattern, line):
                found.append(line.strip())
                event.set()
        event.set()

    threading.Thread(target=pump, daemon=True).start()
    if not event.wait(_READY_S) or not found:
        raise _Failed(f"{name} did not come up within {_READY_S:.0f} s "
                      f"(exit code {proc.poll()}); see {log}")
    return found[0]


def _wait_for_interrupt(procs: list[subprocess.Popen]) -> None:
    try:
        while all(p.poll() is None for p in procs):
            time.sleep(0.5)
        print("liquidtwin demo: a component exited; stopping", file=sys.stderr)
    except KeyboardInterrupt:
        print("\nliquidtwin demo: stopping", file=sys.stderr)


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    deadline = time.monotonic() + 10.0
    for p in procs:
        try:
            p.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
