"""liquidtwin-viewer as a real process: serves its page on 127.0.0.1, stops on SIGTERM."""

import queue
import re
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from viewer_recordings import three_frames, write_clouds

START_TIMEOUT_S = 60


def _console_script() -> str:
    script = Path(sys.executable).with_name("liquidtwin-viewer")
    assert script.exists(), "liquidtwin-viewer is not installed in this environment"
    return str(script)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _lines(stream) -> queue.Queue:
    """Lines of ``stream``, read by a daemon thread so the test never blocks on a pipe."""
    q: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [q.put(line) for line in stream], daemon=True).start()
    return q


def _wait_for_url(lines: queue.Queue, deadline: float, seen: list) -> str:
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.5)
        except queue.Empty:
            continue
        seen.append(line)
        match = re.match(r"liquidtwin-viewer: (http://127\.0\.0\.1:\d+)", line)
        if match:
            return match.group(1)
    raise AssertionError(f"viewer printed no URL in {START_TIMEOUT_S} s:\n{''.join(seen)}")


def _get(url: str) -> tuple[int, bytes]:
    with urllib.request.urlopen(url, timeout=5) as response:
        return response.status, response.read()


def test_viewer_serves_page_and_stops_on_sigterm(tmp_path):
    recording = write_clouds(tmp_path / "r.mcap", three_frames())
    port = _free_port()
    proc = subprocess.Popen(
        [_console_script(), "--mcap", str(recording), "--host", "127.0.0.1", "--port", str(port)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    seen: list[str] = []
    try:
        lines = _lines(proc.stdout)
        deadline = time.monotonic() + START_TIMEOUT_S
        url = _wait_for_url(lines, deadline, seen)
        assert url == f"http://127.0.0.1:{port}"
        status, body = None, b""
        while time.monotonic() < deadline:
            try:
                status, body = _get(url + "/")
                break
            except (urllib.error.URLError, ConnectionError):
                time.sleep(0.2)
        assert status == 200
        assert b"<html" in body.lower()
        assert any("loaded 3 frames (15 points)" in line for line in seen)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            pytest.fail("viewer did not stop within 15 s of SIGTERM")
    assert proc.returncode == 0


def test_viewer_exits_1_on_missing_topic(tmp_path):
    recording = write_clouds(tmp_path / "r.mcap", three_frames())
    run = subprocess.run([_console_script(), "--mcap", str(recording), "--topic", "/nope",
                          "--port", str(_free_port())],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 1
    assert "liquidtwin-viewer: error:" in run.stderr and "'/nope'" in run.stderr


def test_viewer_help():
    run = subprocess.run([_console_script(), "--help"], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0
    for option in ("--mcap", "--port", "--connect", "--prefix", "--session"):
        assert option in run.stdout


@pytest.mark.parametrize("args, message", [(["--prefix", "a/*"], "'*' is a Zenoh wildcard"),
                                           (["--session", "rpc"], "reserved"),
                                           (["--max-hz", "0"], "must be positive")])
def test_viewer_refuses_bad_live_options(args, message):
    run = subprocess.run([_console_script(), *args], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 2 and message in run.stderr


def test_playback_advances_the_slider_and_wraps():
    from liquidtwin_viewer import PointCloudSeries
    from liquidtwin_viewer.app import PlaybackViewer

    frames = tuple(f.astype("float32") for f in three_frames())
    series = PointCloudSeries("/particles", np.array([0, 20_000_000, 40_000_000]), frames)
    viewer = PlaybackViewer(series, host="127.0.0.1", port=_free_port())
    try:
        assert viewer.frame.value == 0 and "4 points" in viewer.label.content
        viewer.frame.value = 2
        assert viewer.label.content == "t = 0.040 s · 6 points"
        viewer.speed.value = 10.0
        viewer.playing.value = True
        seen = set()
        deadline = time.monotonic() + 10
        while len(seen) < 3 and time.monotonic() < deadline:
            seen.add(int(viewer.frame.value))
            time.sleep(0.005)
        assert seen == {0, 1, 2}  # wrapped from the last frame back to the first
        viewer.playing.value = False
        time.sleep(0.3)
        still = viewer.frame.value
        time.sleep(0.3)
        assert viewer.frame.value == still
    finally:
        viewer.stop()
