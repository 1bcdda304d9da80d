"""The live viser page: one session's particles, objects, cameras, overlay and plots.

A render thread wakes at most ``max_hz`` times a second, takes a snapshot of the selected
session's buffer (see :mod:`.subscribe`) and pushes what changed to the browsers. Zenoh
callbacks never wait for it; while paused the buffers keep filling and the view stays.
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
import viser

from .app import page_url
from .buffers import SessionSnapshot
from .colormap import auto_vmax, pose_to_viser, speed_colors
from .panel import NO_SESSION, Panel, status_line
from .subscribe import LiveFeed

log = logging.getLogger("liquidtwin_viewer")

_OBJECT_RGB = (170, 170, 180)
_CONTAINER_RGB = (200, 210, 225)
_CAMERA_RGB = (230, 120, 30)
_SLOW_UPDATE_S = 0.25  # status line and plots refresh at most this often
_OVERLAY_UPDATE_S = 0.1  # the overlay image at most this often
_SESSIONS_UPDATE_S = 1.0


class LiveViewer:
    """Serves the live page of the sessions seen by ``feed``.

    Args:
        feed: started LiveFeed (or one driven by hand in tests).
        host, port: where the page listens (viser moves to the next port if taken).
        session: session to select when it appears (default: the first one).
        point_size: drawn particle size, m.
        max_hz: most view updates per second.
        frustum_scale: drawn camera frustum size, m.
        run_thread: start the render thread (False: call :meth:`render_once` yourself).
    """

    def __init__(self, feed: LiveFeed, *, host: str = "127.0.0.1", port: int = 8080,
                 session: str | None = None, point_size: float = 0.005, max_hz: float = 30.0,
                 frustum_scale: float = 0.05, run_thread: bool = True):
        if not max_hz > 0:
            raise ValueError(f"max_hz must be positive, got {max_hz}")
        self.feed, self.host = feed, host
        self.point_size, self.max_hz, self.frustum_scale = point_size, max_hz, frustum_scale
        self.wanted = session
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.scene.set_up_direction("+y")
        self.server.scene.add_grid("/grid", width=1.0, height=1.0, plane="xz",
                                   cell_size=0.05, section_size=0.25)
        self.panel = Panel(self.server.gui, feed.config.window_s, on_session=self._request,
                           on_pause=lambda: self.set_paused(not self._paused),
                           on_frame=self._reframe)
        self._selected: str | None = None
        self._pending: str | None = None  # asked for from the dropdown (GUI thread)
        self._cloud = None
        self._paused = False
        self._reset_drawn()
        self._renders: list[float] = []  # monotonic times of particle updates pushed
        self._stop = threading.Event()
        self.server.on_client_connect(self._on_connect)
        self._thread = threading.Thread(target=self._loop, name="liquidtwin-render", daemon=True)
        if run_thread:
            self._thread.start()

    # ----------------------------------------------------------------------------- public
    @property
    def port(self) -> int:
        return self.server.get_port()

    @property
    def url(self) -> str:
        """Address to open in a browser."""
        return page_url(self.host, self.port)

    @property
    def selected(self) -> str | None:
        """Session shown now, or None."""
        return self._selected

    @property
    def paused(self) -> bool:
        return self._paused

    def set_paused(self, paused: bool) -> None:
        """Freeze (True) or resume (False) the view; buffering goes on meanwhile."""
        self._paused = bool(paused)
        self.panel.set_paused(self._paused)

    def render_hz(self, window_s: float = 2.0) -> float:
        """Particle updates pushed to the page per second over the last ``window_s``."""
        now = time.monotonic()
        recent = [t for t in self._renders if t >= now - window_s]
        return (len(recent) - 1) / (recent[-1] - recent[0]) if len(recent) > 2 else 0.0

    def stop(self) -> None:
        """Stop rendering and the web server (the feed is the caller's)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self.server.stop()

    def render_once(self) -> None:
        """One view update: session list, then whatever changed in the selected session."""
        now = time.monotonic()
        if now - self._sessions_at >= _SESSIONS_UPDATE_S:
            self._sessions_at = now
            self._update_sessions()
        if self._pending is not None and self._pending != self._selected:
            self._select(self._pending)
        sid = self._selected
        if sid is None:
            self.panel.status.content = (
                f"waiting for sessions under `{self.feed.config.prefix}/`")
            return
        snap = self.feed.snapshot(sid)
        slow = now - self._slow_at >= _SLOW_UPDATE_S
        if slow:
            self._slow_at = now
            status = self.feed.status(sid)
            self.panel.status.content = status_line(
                snap, paused=self._paused, render_hz=self.render_hz(),
                state=status.state if status is not None else "")
        if self._paused or snap.version == self._drawn["version"]:
            return
        self._drawn["version"] = snap.version
        if snap.meshes is not self._drawn["meshes"]:
            self._draw_meshes(snap)
        if snap.poses is not self._drawn["poses"] or snap.cameras is not self._drawn["cameras"]:
            self._place(snap)
        if snap.frames != self._drawn["frames"] and snap.particles is not None:
            self._draw_particles(snap)
        if (snap.overlay_version != self._drawn["overlay"] and snap.overlay is not None
                and now - self._overlay_at >= _OVERLAY_UPDATE_S):
            self._overlay_at = now
            self._draw_overlay(snap)
        if slow:
            self.panel.plot(snap)
            if self._vmax is not None:
                self.panel.set_legend(self._vmax)

    def frame_view(self, center: np.ndarray, reach: float) -> None:
        """Point every browser's camera (and the reset view) at ``center`` (3,) m from
        ``reach`` m away."""
        eye = np.asarray(center, np.float64) + reach * np.array([0.9, 0.7, 1.1])
        self.server.initial_camera.position = eye
        self.server.initial_camera.look_at = center
        for client in self.server.get_clients().values():
            client.camera.position = eye
            client.camera.look_at = center
        self._view = (np.asarray(center, np.float64), float(reach))

    # ------------------------------------------------------------------------- building
    def _reset_drawn(self) -> None:
        self._drawn = {"version": -1, "meshes": None, "poses": None, "cameras": None,
                       "frames": -1, "overlay": -1}
        self._mesh_handles: dict = {}
        self._frustums: dict = {}
        self._vmax: float | None = None
        self._view: tuple | None = None
        self._slow_at = self._overlay_at = self._sessions_at = -1e9

    # -------------------------------------------------------------------------- drawing
    def _draw_particles(self, snap: SessionSnapshot) -> None:
        p = snap.particles
        self._drawn["frames"] = snap.frames
        speed = p.speed if len(p.speed) else np.zeros(0, np.float32)
        self._vmax = auto_vmax(speed, self._vmax) if len(speed) else (self._vmax or 0.05)
        self._cloud = self.server.scene.add_point_cloud(
            "/particles", points=p.points, colors=speed_colors(speed, self._vmax),
            point_size=self.point_size, precision="float32", point_shape="circle")
        self._renders.append(time.monotonic())
        del self._renders[:-200]
        if self._view is None and len(p.points):
            lo, hi = p.points.min(axis=0), p.points.max(axis=0)
            self.frame_view((lo + hi) / 2, max(float(np.linalg.norm(hi - lo)), 0.1) * 1.5)

    def _draw_meshes(self, snap: SessionSnapshot) -> None:
        for handle in self._mesh_handles.values():
            handle.remove()
        self._mesh_handles = {}
        for m in snap.meshes or ():
            self._mesh_handles[m.name] = self.server.scene.add_mesh_simple(
                f"/objects/{m.name}", m.vertices, m.faces, side="double",
                color=_CONTAINER_RGB if m.container else _OBJECT_RGB,
                opacity=0.45 if m.container else None, visible=False)
        self._drawn["meshes"] = snap.meshes
        self._drawn["poses"] = None  # place the new meshes

    def _place(self, snap: SessionSnapshot) -> None:
        self._drawn["poses"], self._drawn["cameras"] = snap.poses, snap.cameras
        initial = self._initial_poses(snap.session)
        for name, handle in self._mesh_handles.items():
            pose = snap.poses.get(name, initial.get(name))
            if pose is not None:
                handle.position, handle.wxyz = pose_to_viser(pose)
                handle.visible = True
        for name, cam in snap.cameras.items():
            pose = snap.poses.get(name, initial.get(name))
            if pose is None:
                continue
            position, wxyz = pose_to_viser(pose)
            handle = self._frustums.get(name)
            if handle is None or (handle.fov, handle.aspect) != (cam.fov_y, cam.aspect):
                if handle is not None:
                    handle.remove()
                handle = self._frustums[name] = self.server.scene.add_camera_frustum(
                    f"/cameras/{name}", fov=cam.fov_y, aspect=cam.aspect,
                    scale=self.frustum_scale, color=_CAMERA_RGB, thickness=0.002)
            handle.position, handle.wxyz = position, wxyz

    def _draw_overlay(self, snap: SessionSnapshot) -> None:
        self._drawn["overlay"] = snap.overlay_version
        shown = self.panel.show_overlay(snap.overlay_camera, snap.overlay, snap.metrics)
        frustum = self._frustums.get(snap.overlay_camera)
        if frustum is not None:
            frustum.image = shown

    def _initial_poses(self, session: str) -> dict:
        """Poses from the session's spec (objects' and cameras' initial poses), if listed."""
        status = self.feed.status(session)
        if status is None:
            return {}
        out = {o.name: np.asarray(o.initial_pose) for o in status.spec.scene.objects
               if len(o.initial_pose) == 7}
        out.update({c.name: np.asarray(c.pose) for c in status.spec.cameras
                    if len(c.pose) == 7})
        return out

    def _update_sessions(self) -> None:
        ids = self.feed.sessions()
        self.panel.set_sessions(ids)  # may reset the menu's value (then on_update asks)
        if self._selected is None and ids:
            pick = self.wanted if self.wanted in ids else ids[0]
            self.panel.session_menu.value = pick
            self._select(pick)

    def _request(self, session: str) -> None:
        if session != NO_SESSION:
            self._pending = session

    def _select(self, session: str) -> None:
        """Show ``session`` from now on (render thread only)."""
        self._selected = self._pending = session
        for handle in (*self._mesh_handles.values(), *self._frustums.values()):
            handle.remove()
        if self._cloud is not None:
            self._cloud.remove()
            self._cloud = None
        self.panel.reset()
        self._reset_drawn()

    def _reframe(self) -> None:
        sid = self._selected
        snap = self.feed.snapshot(sid) if sid else None
        if snap is not None and snap.particles is not None and len(snap.particles.points):
            pts = snap.particles.points
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            self.frame_view((lo + hi) / 2, max(float(np.linalg.norm(hi - lo)), 0.1) * 1.5)

    def _on_connect(self, client) -> None:
        if self._view is not None:
            center, reach = self._view
            client.camera.position = center + reach * np.array([0.9, 0.7, 1.1])
            client.camera.look_at = center

    def _loop(self) -> None:
        period = 1.0 / self.max_hz
        due = time.monotonic()
        while not self._stop.is_set():
            try:
                self.render_once()
            except Exception:  # keep the page alive; the cause goes to the log
                log.exception("liquidtwin-viewer: render failed")
                self._stop.wait(1.0)
            # A fixed schedule keeps the average rate at max_hz despite late wake-ups; after a
            # long stall it restarts instead of bursting to catch up.
            now = time.monotonic()
            due = max(due + period, now)
            self._stop.wait(due - now)
