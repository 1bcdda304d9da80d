"""The live page in a real browser: ``liquidtwin-viewer`` as a process against a Zenoh peer
that this test opens (playing the server), loaded in headless chromium (Playwright)."""

import io
import queue
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from live_fakes import BOTH, MODEL, OBSERVED, FakeService, box_mesh, free_port

from liquidtwin_viewer import open_zenoh

CHROMIUM = Path("/usr/bin/chromium")
pytestmark = pytest.mark.skipif(not CHROMIUM.exists(),
                                reason="needs Debian's chromium at /usr/bin/chromium "
                                "(make test installs it via APT_PACKAGES)")
SESSION = "pour-1"
WAIT_S = 30  # bound on every wait


def _start_viewer(zenoh_port: int, web_port: int):
    script = Path(sys.executable).with_name("liquidtwin-viewer")
    proc = subprocess.Popen(
        [str(script), "--connect", f"tcp/127.0.0.1:{zenoh_port}", "--port", str(web_port)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True).start()
    seen, deadline = [], time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.5)
        except queue.Empty:
            if proc.poll() is not None:
                break
            continue
        seen.append(line)
        match = re.match(r"liquidtwin-viewer: (http://127\.0\.0\.1:\d+)$", line.strip())
        if match:
            return proc, match.group(1)
    proc.kill()
    raise AssertionError("viewer printed no URL:\n" + "".join(seen))


def _rgb(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)


def _colourful(region: np.ndarray) -> float:
    """Fraction of pixels whose channels differ by more than 80 (the grid and the
    background are grey; speed colours are not)."""
    return float(((region.max(axis=2) - region.min(axis=2)) > 80).mean())


def _wait(predicate, what: str):
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out after {WAIT_S} s waiting for {what}")


def test_live_page_shows_particles_overlay_and_session():
    from playwright.sync_api import sync_playwright

    zenoh_port, web_port = free_port(), free_port()
    zenoh_session = open_zenoh(listen=f"tcp/127.0.0.1:{zenoh_port}")
    fake = FakeService(zenoh_session, sessions=[SESSION],
                       meshes={SESSION: [box_mesh((0.04, 0.05, 0.04), "cup", True)]})
    proc, stop = None, threading.Event()
    publisher = None
    try:
        proc, url = _start_viewer(zenoh_port, web_port)
        assert url == f"http://127.0.0.1:{web_port}"
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True,
                                         args=["--no-sandbox", "--enable-unsafe-swiftshader"])
            try:
                page = browser.new_page(viewport={"width": 1000, "height": 700})
                page.goto(url)
                _wait(lambda: page.get_by_text("waiting for sessions").count()
                      or page.get_by_text(SESSION).count(), "the page's status line")
                time.sleep(1.0)  # let the first WebGL frame settle
                before = _rgb(page.screenshot())

                def publish():
                    i = 0
                    while not stop.is_set():
                        fake.frame(SESSION, i)  # 8000 particles, overlay, metrics, ...
                        i += 1
                        stop.wait(0.1)  # 10 Hz: software WebGL shares 2 cores

                publisher = threading.Thread(target=publish, daemon=True)
                publisher.start()
                # The session is selected in the dropdown (a text input holding its id).
                _wait(lambda: page.evaluate(
                    "s => [...document.querySelectorAll('input')].some(i => i.value === s)",
                    SESSION), "the session in the dropdown")
                overlay = _wait(lambda: _overlay_img(page), "the overlay image")
                _wait(lambda: "8000 particles" in page.inner_text("body"), "a particle frame")
                time.sleep(1.5)  # camera framing and a few more frames
                after = _rgb(page.screenshot())
                overlay_px = _rgb(overlay.screenshot())
                status = page.inner_text("body")
            finally:
                browser.close()
        # The 3-D view: the camera looks at the particles, so they are at the canvas centre
        # (the GUI panel covers the right side only).
        h, w, _ = after.shape
        box = (slice(h // 2 - 120, h // 2 + 120), slice(w // 2 - 150, w // 2 + 150))
        assert _colourful(before[box]) < 0.02, "colours before any data was sent"
        assert _colourful(after[box]) > 0.2, "particles not drawn at the canvas centre"
        assert np.abs(after[box] - before[box]).mean() > 20
        region = after[box]
        red = (region[..., 0] > 150) & (region[..., 1] < 110) & (region[..., 2] < 110)
        blue = (region[..., 2] > 140) & (region[..., 0] < 90)
        assert red.mean() > 0.01 and blue.mean() > 0.01, "speed colours span slow and fast"
        for colour in (OBSERVED, MODEL, BOTH):
            near = (np.abs(overlay_px - colour) <= 12).all(axis=2).mean()
            assert near > 0.05, f"overlay colour {colour} covers {near:.3f} of the image"
        assert re.search(r"\d+(\.\d+)? Hz drawn", status) and "lag 12 ms" in status
    finally:
        stop.set()
        if publisher is not None:
            publisher.join(timeout=5)
        if proc is not None:
            proc.terminate()
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        fake.close()
        zenoh_session.close()
    assert proc.returncode == 0


def _overlay_img(page):
    """The GUI <img> holding the 160×120 overlay once it arrived, else None."""
    index = page.evaluate("() => [...document.querySelectorAll('img')].findIndex("
                          "i => i.naturalWidth === 160 && i.naturalHeight === 120)")
    return page.locator("img").nth(index) if index >= 0 else None
