"""A session's inbox: the newest pending frame, pending calibrations and masks by stamp.

Filled from the Zenoh callback, emptied by the session's worker (docs/service.md "Real
time"): a frame superseded before the worker takes it counts as ``dropped_stale`` (its poses
are kept under the newer frame's, so no object or camera loses its last pose); a sample not
newer than the last accepted one of its stream (per camera for camera/mask/image) counts as
``dropped_out_of_order``. A frame at stamp t takes the newest mask with stamp ≤ t that no
earlier frame used, if it is at most ``mask_max_age_s`` old. An inbox made with
``keep_images`` (sessions whose masks come from the server's detector) also hands each frame
every pending RGB image with stamp ≤ t, oldest first, so the detector sees every image in
order (its recurrent state integrates them); at most MAX_PENDING_IMAGES per camera wait.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from .config import MAX_PENDING_IMAGES, MAX_PENDING_MASKS
from .inputs import PosesIn, Sample

COUNTERS = ("frames_in", "frames_done", "dropped_stale", "dropped_out_of_order", "rejected")


@dataclass
class Frame:
    """A frame to process: its poses sample, when it arrived (ns since the epoch), the
    calibrations that arrived before it and the mask it uses (camera, (H, W) bool) or None."""

    sample: Sample
    received_ns: int
    cameras: list = field(default_factory=list)
    mask: tuple | None = None
    images: list = field(default_factory=list)      # [(stamp ns, camera, (H, W, 3) uint8 RGB)]


class Inbox:
    """Thread-safe inbox of one session; ``counters`` holds the COUNTERS (shared with metrics)."""

    def __init__(self, counters: dict | None = None, last: dict | None = None, keep_images: bool = False):
        self.cv = threading.Condition()
        self.counters = {k: int((counters or {}).get(k, 0)) for k in COUNTERS}
        self.last = dict(last or {})          # order key -> last accepted stamp ns
        self._frame: Frame | None = None
        self._cameras: list = []
        self._masks: dict[str, list] = {}
        self._images: dict[str, list] = {}
        self.keep_images = keep_images

    def count(self, name: str, n: int = 1) -> None:
        with self.cv:
            self.counters[name] += n

    def accept(self, sample: Sample, received_ns: int, on_accept=None) -> bool:
        """Queue a checked sample; False (and counted) when out of order. ``on_accept(sample)``
        runs under the inbox lock before queuing (the session logs the sample there, so the log
        holds samples in acceptance order)."""
        stamp = int(sample.header.stamp_ns)
        with self.cv:
            key = sample.order_key
            if key in self.last and stamp <= self.last[key]:
                self.counters["dropped_out_of_order"] += 1
                return False
            self.last[key] = stamp
            if on_accept is not None:
                on_accept(sample)
            item = sample.item
            if sample.stream == "poses":
                self.counters["frames_in"] += 1
                if self._frame is not None:
                    self.counters["dropped_stale"] += 1
                    old: PosesIn = self._frame.sample.item
                    item.objects = {**old.objects, **item.objects}
                    item.cameras = {**old.cameras, **item.cameras}
                self._frame = Frame(sample, int(received_ns))
                self.cv.notify_all()
            elif sample.stream == "camera":
                self._cameras.append(item)
            elif sample.stream == "mask":
                pending = self._masks.setdefault(item.camera, [])
                pending.append((stamp, item.mask))
                del pending[:-MAX_PENDING_MASKS]
            elif sample.stream == "image" and self.keep_images:
                pending = self._images.setdefault(item.camera, [])
                pending.append((stamp, item.rgb))
                del pending[:-MAX_PENDING_IMAGES]
            return True

    def take(self, timeout: float, mask_max_age_s: float, stop: threading.Event) -> Frame | None:
        """The pending frame (with its calibrations and mask), waiting up to ``timeout`` s."""
        with self.cv:
            if self._frame is None and not stop.is_set():
                self.cv.wait(timeout)
            frame, self._frame = self._frame, None
            if frame is None:
                return None
            frame.cameras, self._cameras = self._cameras, []
            t = int(frame.sample.header.stamp_ns)
            best = None
            for camera, pending in self._masks.items():
                usable = [(s, m) for s, m in pending if s <= t]
                if usable and (best is None or usable[-1][0] > best[0]):
                    best = (usable[-1][0], camera, usable[-1][1])
                pending[:] = [(s, m) for s, m in pending if s > t]
            if best is not None and t - best[0] <= mask_max_age_s * 1e9:
                frame.mask = (best[1], best[2])
            for camera, pending in self._images.items():
                frame.images += [(s, camera, img) for s, img in pending if s <= t]
                pending[:] = [(s, img) for s, img in pending if s > t]
            frame.images.sort(key=lambda it: it[0])
            return frame

    def wake(self) -> None:
        with self.cv:
            self.cv.notify_all()

    def clear(self) -> None:
        """Forget pending frames, masks and the last stamps (a reset session starts over)."""
        with self.cv:
            self._frame, self._masks, self._images, self.last = None, {}, {}, {}

    def state(self) -> dict:
        """Counters and last stamps (for checkpoints)."""
        with self.cv:
            return {"counters": dict(self.counters), "last": dict(self.last)}
