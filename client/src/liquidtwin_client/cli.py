"""``liquidtwin-client``: the robot-side command line.

Subcommands:
    inspect REC.mcap   list a recording's channels, message counts and time span
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from datetime import datetime, timezone

from .recording import RecordingError, RecordingSummary, summarize_recording


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
    return parser


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
