"""A live detector for a server session: RGB frames in, liquid masks out, per camera.

The network (shared, read-only, between sessions that use the same model file) runs at its
training resolution (``meta["size"]``); each camera keeps its own input encoder (previous
grey frame for the flow) and recurrent state, so two cameras — or two sessions — never mix
their histories. The probability image is resized back to the camera's pixels and
thresholded at the model's ``meta["threshold"]`` (the F1-best threshold on its training
data, written by ``liquidtwin perception train``; 0.5 when absent).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from .data import SIZE
from .inputs import FrameEncoder
from .weights import DEFAULT_MODEL, load_model

_CACHE: dict[str, tuple] = {}
_CACHE_LOCK = threading.Lock()


def shared_model(path=None):
    """(net, meta) for a model file, loaded once per process (weights_only)."""
    key = str(Path(DEFAULT_MODEL if path is None else path).resolve())
    with _CACHE_LOCK:
        if key not in _CACHE:
            _CACHE[key] = load_model(key)
        return _CACHE[key]


class StreamDetector:
    """Liquid masks from RGB frames, keeping per-camera state. Not thread-safe: one caller
    (a session's worker) at a time."""

    def __init__(self, net, meta: dict):
        self.net, self.meta = net, meta
        self.size = tuple(meta.get("size", SIZE))
        self.threshold = float(meta.get("threshold", 0.5))
        self._enc: dict[str, FrameEncoder] = {}
        self._state: dict[str, dict] = {}
        self.last_ms = 0.0

    @classmethod
    def from_file(cls, path=None) -> "StreamDetector":
        return cls(*shared_model(path))

    def reset(self) -> None:
        """Forget every camera's history (a reset session starts a new stream)."""
        self._enc.clear()
        self._state.clear()

    @torch.no_grad()
    def probability(self, camera: str, rgb: np.ndarray) -> np.ndarray:
        """(H, W) float32 liquid probability of one frame of ``camera`` at the frame's size."""
        t0 = time.perf_counter()
        enc = self._enc.setdefault(camera, FrameEncoder(self.net.input_type, self.size))
        x = torch.from_numpy(enc(rgb))[None]
        state = self._state.get(camera) or self.net.initial_state(1, x.shape[2], x.shape[3])
        logits, self._state[camera] = self.net.step(x, state)
        p = torch.sigmoid(logits)[0, 0].numpy()
        h, w = rgb.shape[:2]
        out = p if p.shape == (h, w) else cv2.resize(p, (w, h), interpolation=cv2.INTER_LINEAR)
        self.last_ms = 1e3 * (time.perf_counter() - t0)
        return out

    def __call__(self, camera: str, rgb: np.ndarray) -> np.ndarray:
        """(H, W) bool liquid mask of one frame of ``camera``."""
        return self.probability(camera, rgb) >= self.threshold


def detect_recording(rec, camera: str, detector: "StreamDetector") -> np.ndarray:
    """(M, H, W) bool: ``detector``'s mask for each of ``rec``'s M recorded masks of
    ``camera``, from the newest RGB frame at or before the mask's stamp (as a session does),
    all-False where no frame came yet. Every frame is fed in stamp order from a fresh stream."""
    if camera not in rec.images:
        raise ValueError(f"{rec.path}: no RGB images of camera {camera!r} (generate with --rgb)")
    t_img, images = rec.images[camera]
    t_mask, masks = rec.masks[camera]
    detector.reset()
    detected = [detector(camera, im) for im in images]
    out = np.zeros(np.shape(masks), bool)
    for k, t in enumerate(t_mask):
        i = int(np.searchsorted(t_img, t, side="right")) - 1
        if i >= 0:
            out[k] = detected[i]
    return out
