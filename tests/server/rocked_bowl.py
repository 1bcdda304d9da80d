"""A bowl of liquid seen whole by a camera and rocked gently: the stability check every
tracker must pass (a correction must not pump energy into a large visible liquid body)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from liquidtwin.camera import Camera
from liquidtwin.session import SessionEngine


def bowl_session(tracking: int, tracker_kw: dict):
    """A bowl of ~1.7k particles seen whole by a 640×480 camera, the mask a disc where its
    surface projects, tracked by ``tracking`` (a TrackingMode) with its tracker's attributes
    overridden by ``tracker_kw``. Returns (engine, mask (480, 640) bool)."""
    spec = pb.SessionSpec(tracking=tracking)
    spec.scene.name = "bowl"
    spec.scene.simulation.h, spec.scene.simulation.dt, spec.scene.simulation.iterations = 0.011, 1 / 60, 4
    spec.scene.simulation.spacing = 0.55 * 0.011
    bowl = spec.scene.objects.add(name="bowl", model="bowl", container=True)
    bowl.initial_pose.extend([0, 0, 0, 0, 0, 0, 1])
    spec.scene.fills.add(container="bowl", volume_ml=150.0)
    eng = SessionEngine.create(spec)
    for k, v in tracker_kw.items():
        setattr(eng._tracker, k, v)
    cam = Camera.look_at((0.0, 0.35, 0.30), (0.0, 0.03, 0.0), width=640, height=480, fov_y_deg=45.0)
    eng.set_camera("cam", K=cam.K.double().numpy(), D=np.zeros(5), width=640, height=480,
                   pose=cam.pose.double().numpy())
    ring = torch.tensor([[0.07 * math.cos(a), 0.03, 0.07 * math.sin(a)]
                         for a in np.linspace(0, 2 * math.pi, 48, endpoint=False)], dtype=torch.float64)
    uv, _ = cam.project(ring.to(cam.K.dtype))
    mask = np.zeros((480, 640), np.uint8)
    cv2.fillPoly(mask, [uv.detach().numpy().round().astype(np.int32)], 1)
    return eng, mask.astype(bool)


def rock(eng, mask, frames: int) -> tuple[int, float]:
    """Rock the bowl ±8° at 0.5 Hz for ``frames`` 30 Hz frames, correcting every frame:
    (particles left in the session, fastest particle m/s)."""
    fastest = 0.0
    for i in range(frames):
        a = math.radians(8.0) * math.sin(math.pi * i / 30)
        eng.advance(i / 30, {"bowl": [0, 0, 0, math.sin(a / 2), 0, 0, math.cos(a / 2)]})
        eng.correct("cam", mask)
        fastest = max(fastest, float(eng.speeds().max()))
    return eng.n_particles, fastest
