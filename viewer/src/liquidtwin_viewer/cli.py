"""``liquidtwin-viewer``: show liquidtwin particles in a web page (viser)."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class ViewerConfig:
    """Settings of one viewer process.

    Attributes:
        mcap: recording to play back.
        topic: MCAP topic of the foxglove.PointCloud messages.
        host: interface the web page listens on.
        port: TCP port of the web page (the next free one if taken).
        point_size: drawn point size, m.
    """

    mcap: Path
    topic: str = "/particles"
    host: str = "127.0.0.1"
    port: int = 8080
    point_size: float = 0.01


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``liquidtwin-viewer``."""
    parser = argparse.ArgumentParser(
        prog="liquidtwin-viewer",
        description="Show liquidtwin particle clouds in a web page: play back the "
        "foxglove.PointCloud messages of an MCAP recording with a time slider.",
    )
    parser.add_argument("--mcap", type=Path, required=True, metavar="REC.mcap",
                        help="recording to play back")
    parser.add_argument("--topic", default=ViewerConfig.topic,
                        help="topic of the foxglove.PointCloud messages (default: %(default)s)")
    parser.add_argument("--host", default=ViewerConfig.host,
                        help="interface to listen on (default: %(default)s)")
    parser.add_argument("--port", type=int, default=ViewerConfig.port,
                        help="port of the web page (default: %(default)s)")
    parser.add_argument("--point-size", type=float, default=ViewerConfig.point_size,
                        help="drawn point size in metres (default: %(default)s)")
    return parser


def parse_config(argv: list[str] | None = None) -> ViewerConfig:
    """Parse the command line into a ViewerConfig."""
    args = build_parser().parse_args(argv)
    return ViewerConfig(mcap=args.mcap, topic=args.topic, host=args.host, port=args.port,
                        point_size=args.point_size)


def main(argv: list[str] | None = None) -> int:
    """Load the recording, serve the page until SIGINT/SIGTERM; returns the exit code."""
    config = parse_config(argv)
    # Imported here so that --help and argument errors stay fast.
    from .app import PlaybackViewer
    from .pointclouds import RecordingError, load_point_clouds

    try:
        series = load_point_clouds(config.mcap, config.topic)
    except RecordingError as exc:
        print(f"liquidtwin-viewer: error: {exc}", file=sys.stderr)
        return 1
    npts = sum(len(f) for f in series.frames)
    print(f"loaded {len(series)} frames ({npts} points) from {config.mcap} {config.topic}",
          flush=True)
    try:
        viewer = PlaybackViewer(series, host=config.host, port=config.port,
                                point_size=config.point_size)
    except OSError as exc:
        print(f"liquidtwin-viewer: error: cannot serve on {config.host}:{config.port}: {exc}",
              file=sys.stderr)
        return 1
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    print(f"liquidtwin viewer: {viewer.url}", flush=True)
    try:
        while not done.wait(0.5):
            pass
    finally:
        viewer.stop()
    return 0
