"""What the world's sensors see: liquid masks, liquid thickness, object silhouettes.

The world's "thermal camera" is deliberately not liquidtwin's model mask (5 px discs at
particle centres, SPEC §2): it draws each visible particle as the projection of a sphere of
the particle's physical radius (so its size shrinks with depth), blurs the result like a
thermal imager's optics and thresholds it. Tracking that compares its own model mask with
these observations therefore faces a real, not a self-generated, mask.
"""

from __future__ import annotations


import cv2
import numpy as np
import torch

from ..camera import Camera, visible
from ..camera.render import sphere_coverage, sphere_radius_px
from ..sim.packing import particle_radius  # noqa: F401  (re-exported: the generator's radius)
from ..scenes.motions import transform


def liquid_mask(camera: Camera, x: torch.Tensor, objects, poses: torch.Tensor, radius_m: float,
                blur_px: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The true liquid mask and a thickness image seen by ``camera``.

    Args:
      x: (N, 3) world particle positions, m. objects/poses: occluders (SDF grids, (M, 7)).
      radius_m: physical particle radius, m. blur_px: optics blur (Gaussian σ, px).
    Returns:
      (mask (H, W) bool, thickness (H, W) float32 — visible particles covering each pixel).
    """
    H, W = camera.height, camera.width
    x = x.detach().to(torch.float64)
    seen = visible(camera, x, objects, poses.to(torch.float64), margin_px=12.0, near=0.02)
    uv, depth = camera.project(x)
    uv, depth = uv[seen], depth[seen]
    thick = np.zeros((H, W), np.float32)
    mask = np.zeros((H, W), bool)
    if uv.shape[0]:
        r_px = sphere_radius_px(camera.fx, depth, radius_m, min_px=0.6)
        thick = sphere_coverage(uv, r_px, None, H, W).numpy().astype(np.float32)
        mask = thick > 0                                 # model_mask ≡ coverage > 0
    if blur_px > 0:
        soft = cv2.GaussianBlur(mask.astype(np.float32), (0, 0), blur_px)
        mask = soft > 0.5
    return mask, thick


def object_labels(camera: Camera, meshes, poses: np.ndarray) -> np.ndarray:
    """Object silhouettes: (H, W) int32, 0 = background, k + 1 = object k (nearest wins,
    painter's order by distance of each object's centre). ``meshes``: trimesh meshes in
    their object frames; ``poses``: (M, 7) object → world."""
    H, W = camera.height, camera.width
    labels = np.zeros((H, W), np.int32)
    eye = camera.pose[:3].detach().cpu().double().numpy()
    order = []
    for k, (mesh, pose) in enumerate(zip(meshes, poses)):
        if mesh is None:
            continue
        verts = transform(np.asarray(pose, float), np.asarray(mesh.vertices, float))
        order.append((-np.linalg.norm(verts.mean(0) - eye), k, verts, np.asarray(mesh.faces)))
    for _, k, verts, faces in sorted(order, key=lambda o: o[0]):
        uv, depth = camera.project(torch.from_numpy(verts))
        uv, depth = uv.numpy(), depth.numpy()
        tri = faces[(depth[faces] > 0.02).all(1)]
        if not len(tri):
            continue
        pts = np.round(uv[tri] * 16).astype(np.int32)       # 4 fractional bits
        layer = np.zeros((H, W), np.uint8)
        cv2.fillPoly(layer, list(pts), 1, lineType=cv2.LINE_8, shift=4)
        labels[layer > 0] = k + 1
    return labels
