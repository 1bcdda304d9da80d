"""``liquidtwin-client inspect``: summaries of good recordings, clear errors for bad ones."""

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap.writer import Writer
from mcap_protobuf.schema import register_schema

from liquidtwin_client import ChannelSummary, RecordingError, summarize_recording
from liquidtwin_client.cli import main

T0 = 1_700_000_000_000_000_000  # ns


def write_recording(path, *, statistics: bool = True):
    """Write 3 foxglove.PointCloud on /particles (T0, T0+0.5 s, T0+2 s), 2 schemaless JSON
    messages on /metrics (T0+1 s, T0+1.5 s) and an empty channel /idle.

    statistics=False leaves the Statistics record out, so readers must scan messages.
    """
    with open(path, "wb") as f:
        writer = Writer(f, use_statistics=statistics)
        writer.start(profile="", library="liquidtwin-tests")
        schema = register_schema(writer, PointCloud)
        particles = writer.register_channel("/particles", "protobuf", schema)
        metrics = writer.register_channel("/metrics", "json", 0)
        writer.register_channel("/idle", "json", 0)
        for i, dt in enumerate((0.0, 0.5, 2.0)):
            cloud = PointCloud(frame_id="world", point_stride=12, data=struct.pack("<3f", i, 0, 0))
            t = T0 + int(dt * 1e9)
            writer.add_message(particles, t, cloud.SerializeToString(), t)
        for dt in (1.0, 1.5):
            t = T0 + int(dt * 1e9)
            writer.add_message(metrics, t, json.dumps({"iou": 0.9}).encode(), t)
        writer.finish()
    return path


@pytest.fixture
def recording(tmp_path):
    return write_recording(tmp_path / "rec.mcap")


EXPECTED = (
    ChannelSummary("/idle", "", "", "json", 0),
    ChannelSummary("/metrics", "", "", "json", 2),
    ChannelSummary("/particles", "foxglove.PointCloud", "protobuf", "protobuf", 3),
)


def test_summary_from_statistics(recording):
    s = summarize_recording(recording)
    assert s.indexed
    assert s.channels == EXPECTED
    assert s.message_count == 5
    assert (s.start_ns, s.end_ns) == (T0, T0 + 2_000_000_000)
    assert s.duration_s == pytest.approx(2.0)
    assert s.library == "liquidtwin-tests"


def test_summary_by_scanning_matches_statistics(tmp_path):
    s = summarize_recording(write_recording(tmp_path / "scan.mcap", statistics=False))
    assert not s.indexed
    assert s.channels == EXPECTED
    assert s.message_count == 5
    assert (s.start_ns, s.end_ns) == (T0, T0 + 2_000_000_000)


def test_cli_prints_channels_and_span(recording, capsys):
    assert main(["inspect", str(recording)]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert "messages:  5" in lines
    assert "duration:  2.000 s" in lines
    assert any(l.split() == ["/particles", "foxglove.PointCloud", "protobuf", "3"] for l in lines)
    assert any(l.split() == ["/metrics", "-", "json", "2"] for l in lines)
    assert "2023-11-14T22:13:20.000000000Z" in out


def test_cli_json(recording, capsys):
    assert main(["inspect", "--json", str(recording)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["message_count"] == 5 and doc["duration_s"] == pytest.approx(2.0)
    assert doc["channels"][2] == {"topic": "/particles", "schema_name": "foxglove.PointCloud",
                                  "schema_encoding": "protobuf", "message_encoding": "protobuf",
                                  "message_count": 3}


def _corrupt_tail(path: Path) -> Path:
    data = bytearray(path.read_bytes())
    # Overwrite the summary section, keeping the footer and both magics intact.
    data[-120:-40] = b"\xff" * 80
    out = path.with_name("corrupt-summary.mcap")
    out.write_bytes(bytes(data))
    return out


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p: p.with_name("missing.mcap"), "no such file"),
        (lambda p: p.parent, "not a regular file"),
        (lambda p: _write(p, b""), "empty file"),
        (lambda p: _write(p, b"PK\x03\x04 definitely a zip" * 4), "not an MCAP file"),
        (lambda p: _write(p, p.read_bytes()[: len(p.read_bytes()) // 2]), "truncated MCAP file"),
        (_corrupt_tail, "corrupt MCAP file"),
    ],
    ids=["missing", "directory", "empty", "not-mcap", "truncated", "corrupt-summary"],
)
def test_bad_files_give_clear_errors(recording, capsys, make, message):
    bad = make(recording)
    with pytest.raises(RecordingError, match=message):
        summarize_recording(bad)
    assert main(["inspect", str(bad)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("liquidtwin-client inspect: error: ") and message in err


def _write(path: Path, data: bytes) -> Path:
    out = path.with_name("bad.mcap")
    out.write_bytes(data)
    return out


def _console_script() -> str:
    script = Path(sys.executable).with_name("liquidtwin-client")
    assert script.exists(), "liquidtwin-client is not installed in this environment"
    return str(script)


def test_console_script_runs_inspect(recording):
    run = subprocess.run([_console_script(), "inspect", str(recording)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert "/particles" in run.stdout


@pytest.mark.parametrize("args", [["--help"], ["inspect", "--help"]])
def test_help(args):
    run = subprocess.run([_console_script(), *args], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.startswith("usage: liquidtwin-client")


def test_usage_errors_exit_2():
    run = subprocess.run([_console_script()], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "required" in run.stderr
    run = subprocess.run([_console_script(), "frobnicate"], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 2 and "invalid choice" in run.stderr
