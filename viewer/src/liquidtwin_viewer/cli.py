"""``liquidtwin-viewer``: show liquidtwin sessions live (Zenoh) or a recording (MCAP) in a
web page (viser)."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"


@dataclass(frozen=True)
class ViewerConfig:
    """Settings of one viewer process.

    Attributes:
        mcap: recording to play back; None for live mode.
        connect: Zenoh endpoint to connect to in live mode (the server's or a router's).
        prefix: Zenoh key prefix of the service.
        session: session to show first in live mode (default: the first one seen).
        window_s: length of the live IOU / volume plots, s.
        max_hz: most live view updates per second.
        topic: MCAP topic of the foxglove.PointCloud messages (playback).
        host: interface the web page listens on.
        port: TCP port of the web page (the next free one if taken).
        point_size: drawn point size, m.
    """

    mcap: Path | None = None
    connect: str = DEFAULT_CONNECT
    prefix: str = "liquidtwin"
    session: str | None = None
    window_s: float = 30.0
    max_hz: float = 30.0
    topic: str = "/particles"
    host: str = "127.0.0.1"
    port: int = 8080
    point_size: float = 0.01


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``liquidtwin-viewer``."""
    parser = argparse.ArgumentParser(
        prog="liquidtwin-viewer",
        description="Show liquidtwin in a web page. Live (default): connect to a "
        "liquidtwin server over Zenoh and draw a session's particles (coloured by speed), "
        "objects, cameras, overlay image and IOU / volume plots. With --mcap: play back "
        "the foxglove.PointCloud messages of a recording with a time slider.",
    )
    parser.add_argument("--connect", default=ViewerConfig.connect, metavar="ENDPOINT",
                        help="Zenoh endpoint of the server or router (default: %(default)s)")
    parser.add_argument("--prefix", default=ViewerConfig.prefix,
                        help="Zenoh key prefix of the service (default: %(default)s)")
    parser.add_argument("--session", default=None,
                        help="session to show first (default: the first one found)")
    parser.add_argument("--window", type=float, default=ViewerConfig.window_s, metavar="S",
                        help="seconds of history in the live plots (default: %(default)s)")
    parser.add_argument("--max-hz", type=float, default=ViewerConfig.max_hz,
                        help="most live view updates per second (default: %(default)s)")
    parser.add_argument("--mcap", type=Path, default=None, metavar="REC.mcap",
                        help="play back this recording instead of going live")
    parser.add_argument("--topic", default=ViewerConfig.topic,
                        help="with --mcap: topic of the foxglove.PointCloud messages "
                        "(default: %(default)s)")
    parser.add_argument("--host", default=ViewerConfig.host,
                        help="interface to listen on (default: %(default)s)")
    parser.add_argument("--port", type=int, default=ViewerConfig.port,
                        help="port of the web page (default: %(default)s)")
    parser.add_argument("--point-size", type=float, default=None,
                        help="drawn point size in metres (default: 0.005 live, 0.01 --mcap)")
    return parser


def parse_config(argv: list[str] | None = None) -> ViewerConfig:
    """Parse the command line into a ViewerConfig."""
    parser = build_parser()
    args = parser.parse_args(argv)
    from liquidtwin_proto import validate_prefix, validate_session_id

    try:
        validate_prefix(args.prefix)
        if args.session is not None:
            validate_session_id(args.session)
    except ValueError as exc:
        parser.error(str(exc))
    if not args.window > 0 or not args.max_hz > 0:
        parser.error("--window and --max-hz must be positive")
    point_size = args.point_size or (ViewerConfig.point_size if args.mcap else 0.005)
    return ViewerConfig(mcap=args.mcap, connect=args.connect, prefix=args.prefix,
                        session=args.session, window_s=args.window, max_hz=args.max_hz,
                        topic=args.topic, host=args.host, port=args.port,
                        point_size=point_size)


def main(argv: list[str] | None = None) -> int:
    """Serve the page until SIGINT/SIGTERM; returns the exit code."""
    config = parse_config(argv)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    return _playback(config) if config.mcap is not None else _live(config)


def _playback(config: ViewerConfig) -> int:
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
        return _cannot_serve(config, exc)
    return _serve(viewer.url, viewer.stop)


def _live(config: ViewerConfig) -> int:
    from .live import LiveViewer
    from .subscribe import FeedConfig, LiveFeed, open_zenoh

    try:
        zenoh_session = open_zenoh(connect=config.connect)
    except Exception as exc:  # zenoh raises its own ZError for bad endpoints
        print(f"liquidtwin-viewer: error: cannot open Zenoh towards {config.connect}: {exc}",
              file=sys.stderr)
        return 1
    feed = LiveFeed(zenoh_session, FeedConfig(prefix=config.prefix, window_s=config.window_s))
    try:
        viewer = LiveViewer(feed, host=config.host, port=config.port, session=config.session,
                            point_size=config.point_size, max_hz=config.max_hz)
    except OSError as exc:
        zenoh_session.close()
        return _cannot_serve(config, exc)
    feed.start()
    print(f"liquidtwin-viewer: live from {config.connect}, prefix {config.prefix!r}",
          flush=True)

    def stop() -> None:
        viewer.stop()
        feed.close()
        zenoh_session.close()

    return _serve(viewer.url, stop)


def _cannot_serve(config: ViewerConfig, exc: OSError) -> int:
    print(f"liquidtwin-viewer: error: cannot serve on {config.host}:{config.port}: {exc}",
          file=sys.stderr)
    return 1


def _serve(url: str, stop) -> int:
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    print(f"liquidtwin-viewer: {url}", flush=True)
    try:
        while not done.wait(0.5):
            pass
    finally:
        stop()
    return 0
