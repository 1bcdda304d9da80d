"""The side panel of the live page: session menu, pause, status line, speed legend,
overlay image and the IOU / volume plots (viser GUI handles)."""

from __future__ import annotations

import numpy as np

from .buffers import Series, SessionSnapshot
from .colormap import legend_image

NO_SESSION = "(waiting for sessions)"
_PLACEHOLDER = np.full((48, 64, 3), 40, np.uint8)  # dark grey, the overlay's background
_PLOT_COLORS = ("#2a6fdb", "#d9482b", "#2b9e4a", "#9b59b6", "#e0a800", "#17a2b8")
_MAX_GUI_IMAGE_W = 480  # wider overlays are subsampled for the panel
_COLOURS = "blue: observed · green: model · yellow: both"


class Panel:
    """GUI handles of the live page, built on ``gui`` (a viser GuiApi).

    Args:
        gui: ``ViserServer.gui``.
        window_s: x range of the plots, s before the newest sample.
        on_session, on_pause, on_frame: called (from viser's thread) with the chosen
            session id / when pause or "frame particles" is clicked.
    """

    def __init__(self, gui, window_s: float, on_session, on_pause, on_frame):
        self._gui = gui
        gui.add_markdown("**liquidtwin** live")
        self.session_menu = gui.add_dropdown("session", (NO_SESSION,))
        self.session_menu.on_update(lambda _: on_session(self.session_menu.value))
        self.pause_button = gui.add_button("pause")
        self.pause_button.on_click(lambda _: on_pause())
        gui.add_button("frame particles").on_click(lambda _: on_frame())
        self.status = gui.add_markdown("starting")
        with gui.add_folder("speed (m/s)"):
            gui.add_image(legend_image(), format="png")
            self.legend_text = gui.add_markdown("0 — ? m/s")
        with gui.add_folder("overlay"):
            self.overlay = gui.add_image(_PLACEHOLDER, format="png", label="no overlay yet")
            self.overlay_text = gui.add_markdown(_COLOURS)
        self._plots = gui.add_folder("plots")
        self._x = {"time": False, "range": (-window_s, 0.0)}
        with self._plots:
            self.iou_plot = gui.add_uplot(
                (np.zeros(0), np.zeros(0)),
                ({"label": "t (s)"}, {"label": "IOU", "stroke": _PLOT_COLORS[0], "width": 2}),
                title="IOU", scales={"x": self._x, "y": {"range": (0.0, 1.0)}}, aspect=2.0)
        self.volume_plot = None
        self._volume_names: tuple[str, ...] = ()

    def set_paused(self, paused: bool) -> None:
        self.pause_button.label = "resume" if paused else "pause"

    def set_sessions(self, ids: list[str]) -> None:
        """Offer ``ids`` in the menu (a placeholder while there are none)."""
        options = tuple(ids) or (NO_SESSION,)
        if options != tuple(self.session_menu.options):
            self.session_menu.options = options

    def set_legend(self, vmax: float) -> None:
        self.legend_text.content = f"0 — {vmax:.2f} m/s (faster clipped)"

    def show_overlay(self, camera: str, image: np.ndarray, metrics) -> np.ndarray:
        """Show an overlay (H, W, 3) uint8; returns the (subsampled) image shown."""
        step = int(np.ceil(image.shape[1] / _MAX_GUI_IMAGE_W))
        small = np.ascontiguousarray(image[::step, ::step])
        self.overlay.image = small
        self.overlay.label = f"{camera} · {image.shape[1]}×{image.shape[0]}"
        info = getattr(metrics, "overlay", None)
        if info is not None and (info.observed_px or info.model_px):
            self.overlay_text.content = (f"observed {info.observed_px} px · model "
                                         f"{info.model_px} px · both {info.overlap_px} px")
        return small

    def plot(self, snap: SessionSnapshot) -> None:
        """Redraw the IOU and volume plots from a snapshot."""
        iou = snap.iou.values.get("iou", np.zeros(0))
        keep = np.isfinite(iou)
        self.iou_plot.data = (snap.iou.t[keep], iou[keep])
        names = tuple(snap.volumes.values)
        if not names:
            return
        data = _rows_without_nan(snap.volumes, names)
        if names == self._volume_names:
            self.volume_plot.data = data
            return
        if self.volume_plot is not None:
            self.volume_plot.remove()
        series = ({"label": "t (s)"}, *({"label": f"{n} (ml)", "width": 2,
                                         "stroke": _PLOT_COLORS[(i + 1) % len(_PLOT_COLORS)]}
                                        for i, n in enumerate(names)))
        with self._plots:
            self.volume_plot = self._gui.add_uplot(data, series, title="volumes (ml)",
                                                   scales={"x": self._x}, aspect=2.0)
        self._volume_names = names

    def reset(self) -> None:
        """Forget the previous session's overlay and plots."""
        self.overlay.image = _PLACEHOLDER
        self.overlay.label = "no overlay yet"
        self.overlay_text.content = _COLOURS
        self.iou_plot.data = (np.zeros(0), np.zeros(0))
        if self.volume_plot is not None:
            self.volume_plot.remove()
        self.volume_plot, self._volume_names = None, ()


def status_line(snap: SessionSnapshot, *, paused: bool, render_hz: float, state: str) -> str:
    """The one-line status of a session: frames, rates, lag, particles, problems."""
    parts = [f"**{snap.session}**", "paused" if paused else "live", f"{snap.frames} frames",
             f"{snap.fps:.1f} fps in", f"{render_hz:.1f} Hz drawn"]
    m = snap.metrics
    if m is not None:
        parts.append(f"lag {m.lag_ms:.0f} ms")
        if m.sim_lag_s > 0:
            parts.append(f"sim lag {m.sim_lag_s:.2f} s")
    if np.isfinite(snap.age_s):
        parts.append(f"last {snap.age_s:.1f} s ago")
    if snap.particles is not None:
        parts.append(f"{len(snap.particles.points)} particles")
    if snap.rejected:
        parts.append(f"{snap.rejected} undecodable ({snap.last_error[:80]})")
    if state:
        parts.append(state)
    return " · ".join(parts)


def _rows_without_nan(series: Series, names) -> tuple:
    keep = np.all([np.isfinite(series.values[n]) for n in names], axis=0)
    return (series.t[keep], *(series.values[n][keep] for n in names))
