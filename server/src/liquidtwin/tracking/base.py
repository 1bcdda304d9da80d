"""The tracker interface: what a closed-loop tracker sees and what it may change.

A tracker turns one camera observation into a correction of the particles. The session
engine builds the :class:`Observation` (projection, occlusion and coverage computed once and
shared with the IOU and the overlay), calls :meth:`Tracker.correct`, and applies the returned
:class:`Correction` to the **visible** particles only, with anti-clipped moves (a correction
never pushes liquid through a wall). Trackers are small objects with optional state of their
own (:meth:`Tracker.state_dict`), so MAP filters or learned perception models can plug in.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import torch

from ..camera import Camera
from ..sim import FluidModel


@dataclass(frozen=True, eq=False)
class Observation:
    """One camera frame as a tracker sees it, with the model's particles at that instant.

    Attributes:
      camera: the calibrated :class:`~liquidtwin.camera.Camera` (image H × W px).
      mask: (H, W) bool observed liquid, True = liquid.
      x: (N, 3) particle positions, m, world frame (the engine's state order).
      v: (N, 3) particle velocities, m/s.
      uv: (N, 2) projected positions, px (OpenCV pixel centres).
      depth: (N,) camera-frame depth of each particle, m.
      visible: (N,) bool, in front of the camera, in the image and not occluded.
      coverage: (H, W) int32 coverage Φ of the visible particles (each drawn as its projected
        sphere, ``camera.render.sphere_coverage``).
      radius_px: typical (median) disc radius of the visible particles, px.
      model: the session's :class:`~liquidtwin.sim.FluidModel` (kernel radius h, objects).
      poses: (M, 7) object poses now.
    """

    camera: Camera
    mask: torch.Tensor
    x: torch.Tensor
    v: torch.Tensor
    uv: torch.Tensor
    depth: torch.Tensor
    visible: torch.Tensor
    coverage: torch.Tensor
    radius_px: float
    model: FluidModel
    poses: torch.Tensor


@dataclass(frozen=True, eq=False)
class Correction:
    """What a tracker wants changed: ``dx`` (N, 3) position change, m, and ``dv`` (N, 3)
    velocity change, m/s, or None. Rows of particles that are not visible are ignored."""

    dx: torch.Tensor
    dv: torch.Tensor | None = None


class Tracker(ABC):
    """A closed-loop tracker. Subclasses set ``name`` and implement :meth:`correct`."""

    name: ClassVar[str] = "tracker"

    @abstractmethod
    def correct(self, obs: Observation) -> Correction | None:
        """The correction for one observation, or None to leave the particles alone."""

    def terms(self) -> tuple:
        """Extra :class:`~liquidtwin.sim.terms.Term` s the session adds to its PBF step while this
        tracker runs (a correction inside the solver's inner loop, SPNets + perception); they
        read what the last :meth:`correct` stored. Default: none."""
        return ()

    def state_dict(self) -> dict:
        """Internal state (tensors and plain numbers only) for checkpoints."""
        return {}

    def load_state_dict(self, state: dict) -> None:
        """Restore what :meth:`state_dict` returned."""


class OpenLoop(Tracker):
    """Simulate with the tracked object poses only: observations are measured, never used."""

    name = "open_loop"

    def correct(self, obs: Observation) -> Correction | None:
        return None
