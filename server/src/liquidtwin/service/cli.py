"""``liquidtwin serve``: run the liquidtwin server until SIGTERM / SIGINT (docs/service.md)."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time
from pathlib import Path

from .config import DEFAULT_LISTEN, DEFAULT_STATE_DIR, ConfigError, ServeConfig

HELP = "run the liquidtwin server: sessions over Zenoh (RPCs, input/output streams, logs, checkpoints)"


def add_serve_parser(p: argparse.ArgumentParser) -> None:
    """Add ``liquidtwin serve``'s options to ``p``."""
    net = p.add_mutually_exclusive_group()
    net.add_argument("--listen", action="append", metavar="EP",
                     help=f"Zenoh endpoint to listen on (repeatable; default {DEFAULT_LISTEN})")
    net.add_argument("--connect", action="append", metavar="EP",
                     help="Zenoh router endpoint to connect to instead (repeatable); listens on nothing")
    p.add_argument("--prefix", default="liquidtwin", metavar="P", help="key prefix (default: %(default)s)")
    p.add_argument("--device", default="cpu", metavar="cpu|cuda",
                   help="torch device of sessions whose spec names none (default: %(default)s)")
    p.add_argument("--state-dir", default=DEFAULT_STATE_DIR, metavar="D",
                   help="session logs, specs and checkpoints; sessions found here are restored (default: %(default)s)")
    p.add_argument("--checkpoint-s", type=float, default=1.0, metavar="S",
                   help="seconds between checkpoints of a changed session (default: %(default)s)")
    p.add_argument("--max-payload-mb", type=float, default=16.0, metavar="M",
                   help="largest accepted request or input sample, MB (default: %(default)s)")
    p.add_argument("--max-sessions", type=int, default=8, metavar="N", help="most open sessions (default: %(default)s)")
    p.add_argument("--orphan-grace-s", type=float, default=60.0, metavar="S",
                   help="seconds a session whose client vanished lives on (default: %(default)s)")
    p.add_argument("--max-steps-per-frame", type=int, default=8, metavar="K",
                   help="most simulation steps per frame; beyond, the sim clock jumps (default: %(default)s)")
    p.add_argument("--threads", type=int, default=1, metavar="T", help="torch CPU threads (default: %(default)s)")
    p.add_argument("--detector", type=Path, default=None, metavar="MODEL.pt",
                   help="liquid detector for sessions with mask_source 'rgb' (default: the shipped model)")
    p.add_argument("--solve-impacts", action="store_true",
                   help="give each session the solver iterations that liquid falling between its containers "
                        "needs, when its SceneSpec states fewer (the same liquid: reference_iterations at the "
                        "stated count). Solver splash throws liquid back out of where it lands; on the quick "
                        "pouring benchmark this raised tracking IOU by 1.5-2.6 points a pour (README)")
    p.add_argument("--server-id", default="", metavar="ID", help="liveliness id (default: server-<pid>-<random>)")
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"),
                   help="server log level on stderr (default: %(default)s)")


def config_from_args(args: argparse.Namespace) -> ServeConfig:
    """The ServeConfig of parsed ``serve`` arguments (ConfigError when unusable)."""
    return ServeConfig(listen=args.listen or [DEFAULT_LISTEN], connect=args.connect or [], prefix=args.prefix,
                       device=args.device, state_dir=args.state_dir, checkpoint_s=args.checkpoint_s,
                       max_payload_bytes=int(args.max_payload_mb * 1024 * 1024), max_sessions=args.max_sessions,
                       orphan_grace_s=args.orphan_grace_s, max_steps_per_frame=args.max_steps_per_frame,
                       threads=args.threads, server_id=args.server_id, detector=args.detector,
                       solve_impacts=args.solve_impacts)


def native_note(device: str) -> str | None:
    """A warning for the log when sessions on ``device`` would run without the C++ kernels
    (an install whose extension did not build: ``server/native_build.py``); None otherwise."""
    from ..sim import fused

    if not device.startswith("cpu") or fused.available("cpu"):
        return None
    return ("the C++ kernels (liquidtwin._native) are not built, so sessions run the pure-torch path: "
            "the same physics, about 23x slower on a full-size pour. Reinstall the server package with a "
            "C++ compiler (Debian: apt install g++; pip install --no-build-isolation ./server)")


def run_serve(args: argparse.Namespace, engine_factory=None) -> int:
    """Serve until SIGTERM/SIGINT; exit code 2 on a configuration error."""
    logging.basicConfig(level=getattr(logging, args.log_level), stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        cfg = config_from_args(args)
    except ConfigError as exc:
        print(f"liquidtwin serve: {exc}", file=sys.stderr)
        return 2
    import torch

    if cfg.device.startswith("cuda") and not torch.cuda.is_available():
        print(f"liquidtwin serve: --device {cfg.device} asked for, but torch sees no CUDA device here "
              f"(torch {torch.__version__}); use --device cpu", file=sys.stderr)
        return 2
    note = native_note(cfg.device)
    if note:
        print(f"liquidtwin serve: {note}", file=sys.stderr, flush=True)
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    from .server import Server

    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    server = Server(cfg, engine_factory)
    t0 = time.monotonic()
    try:
        server.start()
    except Exception as exc:  # noqa: BLE001 - e.g. the port is taken
        print(f"liquidtwin serve: cannot start on {', '.join(cfg.endpoints)}: {exc}", file=sys.stderr)
        server.stop()
        return 1
    how = "connected to " if cfg.connect else ""
    print(f"liquidtwin serve: ready on {how}{', '.join(cfg.endpoints)} (server {cfg.server_id}, prefix "
          f"{cfg.prefix}, state {cfg.state_dir}); {len(server.sessions)} session(s) restored in "
          f"{time.monotonic() - t0:.2f} s", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        logging.getLogger("liquidtwin.serve").info("shutting down: checkpointing %d session(s)", len(server.sessions))
        server.stop()
    return 0
