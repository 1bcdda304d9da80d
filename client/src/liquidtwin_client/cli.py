"""``liquidtwin-client``: the robot-side command line.

Subcommands:
    inspect REC.mcap   list a recording's channels, message counts and time span
    stream REC.mcap    replay a recording into a new server session, collect the results
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from datetime import datetime, timezone

from liquidtwin_proto import DEFAULT_PREFIX
from liquidtwin_proto.pose_filter import parse_pose_filter

from .connection import (CREATE_TIMEOUT_S, DEFAULT_CONNECT, TRACKING_MODES, Client,
                         ServerError)
from .recording import RecordingError, RecordingSummary, summarize_recording
from .replay import load_replay
from .results import ResultsWriter
from .stream import RATES, StreamAborted, stream_replay
from .summary import format_table


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``liquidtwin-client`` and its subcommands."""
    parser = argparse.ArgumentParser(
        prog="liquidtwin-client",
        description="liquidtwin robot-side client: work with recordings and a liquidtwin server.",
    )
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    inspect = commands.add_parser(
        "inspect",
        help="list a recording's channels, message counts and time span",
        description="List the channels of an MCAP recording (topic, schema, encoding, "
        "message count) and its time span.",
    )
    inspect.add_argument("recording", metavar="REC.mcap", help="MCAP file to read")
    inspect.add_argument("--json", action="store_true", help="print the summary as JSON")
    inspect.set_defaults(run=_inspect)
    _add_stream(commands)
    return parser


def _add_stream(commands) -> None:
    p = commands.add_parser(
        "stream",
        help="replay a recording into a new server session and collect the results",
        description="Create a session from the recording's /scene and camera calibrations, "
        "replay its poses, camera, mask and image samples in stamp order, write every output "
        "to RESULTS.mcap and print a summary (frames answered, mean IOU, final volumes, "
        "latency, drops). The session is closed at the end unless --keep-session.",
    )
    p.add_argument("recording", metavar="REC.mcap", help="MCAP recording to stream")
    p.add_argument("--session", metavar="NAME", default=None,
                   help="session id to create (default: the server picks one)")
    p.add_argument("--rate", choices=RATES, default="realtime",
                   help="realtime: pace by the recorded stamps (the server may drop frames); "
                   "max: send each frame when the previous one's particles came back "
                   "(default: realtime)")
    p.add_argument("--tracking", choices=sorted(TRACKING_MODES), default="warp_field",
                   help="how the server corrects the simulation with the masks "
                   "(default: warp_field)")
    p.add_argument("--masks", choices=("recorded", "rgb"), default="recorded",
                   help="recorded: send the recording's masks; rgb: send only its RGB images and have "
                   "the server's liquid detector make the masks (session mask_source 'rgb') "
                   "(default: recorded)")
    p.add_argument("--pose-filter", metavar="M,RAD[,ACC,ANGACC]", type=_pose_filter, default=None,
                   help="have the session filter the object poses (SessionSpec.pose_filter): the tracker's "
                   "white noise per axis in m and rad, optionally the process noise in m/s² and rad/s² "
                   "(default: poses used as recorded)")
    p.add_argument("--connect", metavar="EP", default=DEFAULT_CONNECT,
                   help=f"Zenoh endpoint of the server or router (default: {DEFAULT_CONNECT})")
    p.add_argument("--prefix", metavar="P", default=DEFAULT_PREFIX,
                   help=f"key prefix of the server (default: {DEFAULT_PREFIX})")
    p.add_argument("--out", metavar="RESULTS.mcap", default=None,
                   help="write every output received to this MCAP file")
    p.add_argument("--json", metavar="SUMMARY.json", default=None,
                   help="also write the summary as JSON")
    p.add_argument("--keep-session", action="store_true",
                   help="leave the session open on the server at the end")
    p.add_argument("--timeout", metavar="S", type=float, default=CREATE_TIMEOUT_S,
                   help="seconds to wait for the server to create the session "
                   f"(default: {CREATE_TIMEOUT_S:g})")
    p.add_argument("--frame-timeout", metavar="S", type=float, default=30.0,
                   help="seconds to wait for a frame's particles (default: 30)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(run=_stream)


def _pose_filter(text: str):
    """--pose-filter: a ``PoseFilter`` from M,RAD[,ACC,ANGACC]."""
    try:
        return parse_pose_filter(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit code (0 ok, 1 failure, 2 usage)."""
    args = build_parser().parse_args(argv)
    return args.run(args)


def _inspect(args: argparse.Namespace) -> int:
    try:
        summary = summarize_recording(args.recording)
    except RecordingError as exc:
        print(f"liquidtwin-client inspect: error: {exc}", file=sys.stderr)
        return 1
    if args.json:
        doc = asdict(summary)
        doc["duration_s"] = summary.duration_s
        print(json.dumps(doc, indent=2))
    else:
        print(format_summary(summary))
    return 0


def _stream(args: argparse.Namespace) -> int:
    def fail(message: str) -> int:
        print(f"liquidtwin-client stream: error: {message}", file=sys.stderr)
        return 1

    try:
        replay = load_replay(args.recording)
    except RecordingError as exc:
        return fail(str(exc))
    if not replay.frames:
        return fail(f"{args.recording}: no poses in the recording, nothing to stream")
    writer = None
    try:
        with Client(connect=args.connect, prefix=args.prefix) as client:
            spec = replay.session_spec()
            if args.masks == "rgb":
                if not any(x.stream == "image" for f in replay.stamps for x in f.samples):
                    return fail(f"{args.recording} has no RGB images for --masks rgb")
                spec.mask_source = "rgb"
            if args.pose_filter is not None:
                spec.pose_filter.CopyFrom(args.pose_filter)
            session = client.create_session(spec, session_id=args.session,
                                            tracking=args.tracking, timeout=args.timeout)
            print(f"session {session.session_id}: {len(replay.frames)} frames of "
                  f"{replay.scene.name or 'scene'} at rate {args.rate}", file=sys.stderr)
            try:
                writer = ResultsWriter(args.out) if args.out else None
                if writer is not None:
                    writer.write_status(session.last_status)
                summary = stream_replay(session, replay, rate=args.rate,
                                        frame_timeout=args.frame_timeout, writer=writer,
                                        tracking=args.tracking, progress=not args.no_progress,
                                        skip=("mask",) if args.masks == "rgb" else ())
            finally:
                _finish(session, writer, keep=args.keep_session)
    except (ServerError, TimeoutError, StreamAborted, ValueError, OSError) as exc:
        return fail(str(exc))
    except KeyboardInterrupt:
        print("liquidtwin-client stream: interrupted", file=sys.stderr)
        return 130
    print(format_table(summary))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(summary.to_json(), f, indent=2)
    if summary.frames_answered == 0:
        return fail("no frame was answered with particles")
    return 0


def _finish(session, writer, *, keep: bool) -> None:
    """Record the final status, close (or detach from) the session, finish RESULTS.mcap."""
    try:
        if keep:
            status = session.status()
            session.detach()
        else:
            status = session.close()
        if writer is not None:
            writer.write_status(status)
    except (ServerError, TimeoutError) as exc:
        print(f"liquidtwin-client stream: warning: could not "
              f"{'query' if keep else 'close'} session {session.session_id}: {exc}",
              file=sys.stderr)
    finally:
        session.detach()
        if writer is not None:
            writer.close()


def format_summary(summary: RecordingSummary) -> str:
    """Human-readable table of a recording summary."""
    lines = [
        f"file:      {summary.path}",
        f"library:   {summary.library or '-'}",
        f"profile:   {summary.profile or '-'}",
        f"messages:  {summary.message_count}"
        + ("" if summary.indexed else "  (no statistics in file; counted by scanning)"),
    ]
    if summary.start_ns is not None:
        lines += [
            f"start:     {_iso(summary.start_ns)}  ({summary.start_ns} ns)",
            f"end:       {_iso(summary.end_ns)}  ({summary.end_ns} ns)",
            f"duration:  {summary.duration_s:.3f} s",
        ]
    else:
        lines.append("time span: - (no messages)")
    header = ("topic", "schema", "encoding", "messages")
    rows = [
        (c.topic, c.schema_name or "-", c.message_encoding, str(c.message_count))
        for c in summary.channels
    ]
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(4)]
    lines.append(f"channels:  {len(rows)}")
    for row in [header, *rows]:
        cells = [row[i].ljust(widths[i]) for i in range(3)] + [row[3].rjust(widths[3])]
        lines.append("  " + "  ".join(cells))
    return "\n".join(lines)


def _iso(ns: int) -> str:
    seconds, rest = divmod(ns, 1_000_000_000)
    stamp = datetime.fromtimestamp(seconds, tz=timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")
    return f"{stamp}.{rest:09d}Z"
