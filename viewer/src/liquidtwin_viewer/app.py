"""A viser page that plays back a ``PointCloudSeries`` with a time slider."""

from __future__ import annotations

import threading

import numpy as np
import viser

from .pointclouds import PointCloudSeries

PARTICLE_COLOR = (40, 120, 230)  # RGB, 0-255
_MAX_PAUSE_S = 1.0  # longest wait between two frames during playback, s


def page_url(host: str, port: int) -> str:
    """Address a browser opens for a page served on ``host``:``port`` (wildcards → loopback)."""
    host = "127.0.0.1" if host in ("0.0.0.0", "") else host
    host = f"[{host}]" if ":" in host else host
    return f"http://{host}:{port}"


class PlaybackViewer:
    """Serves one point-cloud series on a viser page, with frame slider and playback.

    The page has a "frame" slider, a "play" checkbox and a "speed" number (1 = recorded
    pace, using the gaps between log times); the cloud shown is the slider's frame.
    """

    def __init__(
        self,
        series: PointCloudSeries,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        point_size: float = 0.01,
    ):
        """Start the viser server; ``point_size`` is the drawn point size, m."""
        self.series = series
        self.point_size = point_size
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.host = host
        last = len(series) - 1
        gui = self.server.gui
        gui.add_markdown(f"**liquidtwin** · `{series.topic}` · {len(series)} frames")
        self.frame = gui.add_slider("frame", min=0, max=max(last, 1), step=1, initial_value=0,
                                    disabled=last == 0)
        self.playing = gui.add_checkbox("play", initial_value=False, disabled=last == 0)
        self.speed = gui.add_number("speed", 1.0, min=0.01, max=100.0, step=0.01)
        self.label = gui.add_markdown("")
        self._aim_camera()
        self.frame.on_update(lambda _: self.show(int(self.frame.value)))
        self.show(0)
        self._stop = threading.Event()
        self._player = threading.Thread(target=self._play, name="playback", daemon=True)
        self._player.start()

    @property
    def port(self) -> int:
        """Port the page is served on (viser moves on if the requested one is taken)."""
        return self.server.get_port()

    @property
    def url(self) -> str:
        """Address to open in a browser."""
        return page_url(self.host, self.port)

    def show(self, index: int) -> None:
        """Draw frame ``index`` of the series."""
        index = min(max(index, 0), len(self.series) - 1)
        points = self.series.frames[index]
        self.server.scene.add_point_cloud(
            "/particles",
            points=points,
            colors=PARTICLE_COLOR,
            point_size=self.point_size,
            precision="float32",
        )
        t = (self.series.times_ns[index] - self.series.times_ns[0]) * 1e-9
        self.label.content = f"t = {t:.3f} s · {len(points)} points"

    def _aim_camera(self) -> None:
        """Start browsers looking at the bounding box of all frames, z up."""
        points = np.concatenate([f for f in self.series.frames if len(f)] or [np.zeros((1, 3))])
        lo, hi = points.min(axis=0), points.max(axis=0)
        center = (lo + hi) / 2
        reach = max(float(np.linalg.norm(hi - lo)), 1e-3)
        self.server.scene.set_up_direction("+z")
        self.server.initial_camera.look_at = center
        self.server.initial_camera.position = center + reach * np.array([1.2, -1.2, 0.8])

    def stop(self) -> None:
        """Stop playback and the server."""
        self._stop.set()
        self._player.join(timeout=2.0)
        self.server.stop()

    def _play(self) -> None:
        times = self.series.times_ns
        while not self._stop.is_set():
            if not self.playing.value or len(self.series) < 2:
                self._stop.wait(0.05)
                continue
            i = int(self.frame.value)
            nxt = (i + 1) % len(self.series)
            gap_s = float(times[nxt] - times[i]) * 1e-9 if nxt else _MAX_PAUSE_S / 2
            speed = max(float(self.speed.value), 1e-3)
            self._stop.wait(float(np.clip(gap_s / speed, 0.0, _MAX_PAUSE_S)))
            if self.playing.value and int(self.frame.value) == i:
                self.frame.value = nxt
