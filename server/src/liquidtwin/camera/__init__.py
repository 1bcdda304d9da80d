"""Cameras: pinhole projection, occlusion by objects, coverage, model masks, splats, IOU."""

from .occlusion import in_view, segment_blocked, visible
from .pinhole import DISTORTION_MODEL, Camera, matrix_to_quat
from .render import coverage, disc_stencil, iou, model_mask, sphere_coverage, sphere_radius_px, splat

__all__ = [
    "sphere_coverage", "sphere_radius_px",
    "Camera", "DISTORTION_MODEL", "matrix_to_quat", "in_view", "segment_blocked", "visible",
    "coverage", "disc_stencil", "iou", "model_mask", "splat",
]
