"""A bank of hypotheses simulated together: K variants of one scene in one PBF state.

Batching by space: hypothesis k's objects are posed ``k · offset_m`` along world x and its
particles start shifted by the same amount. With the offset far beyond the kernel radius
(default 2 m; the table slab is 0.9 m wide) no neighbour pair and no collision ever mixes
two hypotheses, so one :func:`~liquidtwin.sim.step` advances all K at once (one neighbour
search, one set of fused kernels over K·N particles, one anti-clipping pass over K·M
objects). Each hypothesis is drawn into the camera with its offset subtracted and occluded
by its own objects at the true poses, scored, and (closed loop) corrected by its own
tracker on its own particles.

``Bank.single(k)`` is the same hypothesis alone (offset 0): K of those run one after another
are the sequential baseline the batched bank must reproduce.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch

from ..camera import sphere_coverage, sphere_radius_px, visible
from ..session._cull import cull_fallen
from ..session.engine import MIN_RADIUS_PX, NEAR_M, OCCLUSION_MARGIN_PX
from ..sim import FluidModel, FluidState, collide_move, particle_radius, step
from ..tracking import MapFilter, Observation, OpenLoop, WarpField
from .likelihood import (blur_sigma, blurred, check_comparison, check_radius_scale, disagreement, near,
                         slack_radius)

#: Default distance between neighbouring hypotheses along world x, m.
OFFSET_M = 2.0
TRACKERS = {"open_loop": OpenLoop, "warp_field": WarpField, "map_filter": MapFilter}


@dataclass(frozen=True, eq=False)
class Hypothesis:
    """One variant of the scene.

    Attributes:
      name: its label (``"30 %"``, ``"left_full"``, …).
      objects: (M,) SDF grids of the scene's objects in the scene's order (the variant's geometry).
      x: (N_k, 3) initial particle positions, m, world frame at the scene's own place (N_k may be 0).
      v: (N_k, 3) initial velocities, m/s.
    """

    name: str
    objects: tuple
    x: torch.Tensor
    v: torch.Tensor


def make_tracker(mode: str):
    """A fresh tracker for ``mode`` (open_loop, warp_field, map_filter)."""
    if mode not in TRACKERS:
        raise ValueError(f"unknown tracking mode {mode!r} for inference; known: {', '.join(TRACKERS)}")
    tracker = TRACKERS[mode]()
    if tracker.terms():
        raise ValueError(f"tracking mode {mode!r} adds solver terms; the hypothesis bank cannot batch it")
    return tracker


class Bank:
    """K hypotheses in one simulation (see the module doc).

    Args:
      model: the scene's FluidModel (settings, fluid parameters; its objects are replaced).
      hypotheses: the K :class:`Hypothesis` (same object count M each).
      occluders: indices of the objects that hide liquid from cameras.
      tracking: tracker mode per hypothesis ("open_loop", "warp_field", "map_filter").
      offset_m: spacing of the hypotheses along world x, m (> 10 h).
      shared_occlusion: occlude every hypothesis with hypothesis 0's objects in one ray march
        (exact when the variants differ only in liquid or in parts hidden inside an object,
        like the junction's plugs); False: each with its own objects.
      dtype: particle precision (sessions use float32; at 2 m from the origin float32 resolves
        0.24 µm, so a hypothesis's rounding differs from the same run at the origin).
      first_slot: hypothesis k sits at slot ``first_slot + k`` (offset ``slot · offset_m``).
      radius_scale: each visible particle is drawn as a disc of this × its projected sphere's
        radius in px (as the session engine rounds it; :func:`.likelihood.check_radius_scale`;
        1: as the session engine draws it).
    """

    def __init__(self, model: FluidModel, hypotheses, occluders, *, tracking: str = "open_loop",
                 offset_m: float = OFFSET_M, shared_occlusion: bool = True, dtype=torch.float32,
                 first_slot: int = 0, radius_scale: float = 1.0):
        hyps = list(hypotheses)
        if not hyps:
            raise ValueError("a hypothesis bank needs at least one hypothesis")
        m = len(hyps[0].objects)
        if any(len(h.objects) != m for h in hyps):
            raise ValueError("every hypothesis must have the same number of objects")
        if not (math.isfinite(offset_m) and offset_m > 10 * model.h):
            raise ValueError(f"offset_m {offset_m} must be well beyond the kernel radius h = {model.h} m")
        self.hypotheses, self.occluders, self.offset_m, self.mode = hyps, tuple(occluders), float(offset_m), tracking
        self.base_model, self.shared_occlusion = model, bool(shared_occlusion)
        self.dtype, self.first_slot = dtype, int(first_slot)
        self.radius_scale = check_radius_scale(radius_scale)
        self.M, self.K = m, len(hyps)
        self.models = [model.replace(objects=tuple(h.objects)) for h in hyps]
        self.model = model.replace(objects=tuple(g for h in hyps for g in h.objects))
        self.trackers = [make_tracker(tracking) for _ in hyps]
        self.radius_m = particle_radius(float(model.spacing))
        self.counts = [int(h.x.shape[0]) for h in hyps]
        shift = self._shifts(dtype)
        xs = [h.x.to(dtype) + shift[k] for k, h in enumerate(hyps)]
        vs = [h.v.to(dtype) for h in hyps]
        self.group_of_id = torch.cat([torch.full((n,), k, dtype=torch.long) for k, n in enumerate(self.counts)])
        n = sum(self.counts)
        self.state = None if n == 0 else FluidState(torch.cat(xs), torch.cat(vs), torch.arange(n),
                                                     torch.zeros(self.K * m, 7, dtype=dtype), 0.0)

    def single(self, k: int, *, same_place: bool = False) -> "Bank":
        """Hypothesis ``k`` alone (the sequential baseline): at offset 0, or with
        ``same_place`` at its own slot of this bank (the same float rounding)."""
        return Bank(self.base_model, [self.hypotheses[k]], self.occluders, tracking=self.mode, offset_m=self.offset_m,
                    shared_occlusion=self.shared_occlusion, dtype=self.dtype,
                    first_slot=self.first_slot + k if same_place else 0, radius_scale=self.radius_scale)

    def _shifts(self, dtype) -> torch.Tensor:
        s = torch.zeros(self.K, 3, dtype=dtype)
        s[:, 0] = (self.first_slot + torch.arange(self.K, dtype=dtype)) * self.offset_m
        return s

    def _all_poses(self, poses: torch.Tensor) -> torch.Tensor:
        """(K·M, 7) offset copies of the scene poses (M, 7)."""
        out = poses.to(self.dtype).repeat(self.K, 1).clone()
        out[:, 0] += torch.repeat_interleave(self._shifts(self.dtype)[:, 0], self.M)
        return out

    def start(self, poses) -> None:
        """Put the objects at their (M, 7) poses at time 0 (before the first step)."""
        self._poses = torch.as_tensor(poses)
        if self.state is not None:
            s = self.state
            self.state = FluidState(s.x, s.v, s.ids, self._all_poses(self._poses), s.t)

    def step(self, poses) -> None:
        """One time step; ``poses`` (M, 7) scene object poses at its end."""
        self._poses = torch.as_tensor(poses)
        if self.state is not None:
            self.state = step(self.model, self.state, self._all_poses(self._poses))

    def cull(self) -> None:
        """Drop particles fallen below every object (as sessions do)."""
        if self.state is not None:
            self.state, _ = cull_fallen(self.state, self.model.objects)

    def particles(self, k: int) -> torch.Tensor:
        """(N_k, 3) positions of hypothesis k, m, at its own place, ordered by particle id."""
        if self.state is None:
            return torch.zeros(0, 3)
        x, _ = self.state.by_id()
        ids = torch.sort(self.state.ids).values
        return x[self.group_of_id[ids] == k] - self._shifts(x.dtype)[k]

    def observe(self, camera, mask: torch.Tensor, slack_px: float = 0.0, blur_px: float = 0.0) -> np.ndarray:
        """Score and (closed loop) correct every hypothesis with one observed ``mask`` (H, W)
        bool of ``camera``; returns (K,) float64 pixels where each hypothesis's model mask
        (visible particles drawn as projected spheres of ``radius_scale`` × their radius)
        disagrees with the observation, with a slack of ``slack_px`` or a blur of ``blur_px`` at 640×480
        (:func:`.likelihood.disagreement`; both 0: exact)."""
        mask = torch.as_tensor(mask, dtype=torch.bool)
        check_comparison(slack_px, blur_px)
        out = np.zeros(self.K, np.float64)
        radius = slack_radius(camera.height, camera.width, slack_px)
        sigma = blur_sigma(camera.height, camera.width, blur_px)
        mask_np = mask.cpu().numpy()
        mask_blur = blurred(mask_np, sigma)
        nothing = disagreement(np.zeros_like(mask_np), mask_np, radius, sigma_px=sigma, observed_blurred=mask_blur)
        if self.state is None:
            out[:] = nothing
            return out
        mask_near = near(mask_np, radius)
        s = self.state
        group = self.group_of_id[s.ids]
        poses = self._poses.to(s.x.dtype)            # the scene's own poses now
        shift = self._shifts(s.x.dtype)
        x_all = s.x - shift[group]                   # every hypothesis at the scene's own place
        occ_poses = poses[list(self.occluders)]
        if self.shared_occlusion:                    # one ray march for all hypotheses
            seen_all = visible(camera, x_all, [self.models[0].objects[j] for j in self.occluders], occ_poses,
                               margin_px=OCCLUSION_MARGIN_PX, near=NEAR_M)
        uv_all, depth_all = camera.project(x_all)
        r_all = sphere_radius_px(camera.fx, depth_all, self.radius_m, min_px=MIN_RADIUS_PX) * self.radius_scale
        new_x, new_v = s.x.clone(), s.v.clone()
        changed = False
        for k in range(self.K):
            idx = (group == k).nonzero().squeeze(1)
            if idx.numel() == 0:
                out[k] = nothing
                continue
            xk, vk = x_all[idx], s.v[idx]
            uv, depth, r_px = uv_all[idx], depth_all[idx], r_all[idx]
            if self.shared_occlusion:
                seen = seen_all[idx]
            else:
                occ = [self.models[k].objects[j] for j in self.occluders]
                seen = visible(camera, xk, occ, occ_poses, margin_px=OCCLUSION_MARGIN_PX, near=NEAR_M)
            cov = sphere_coverage(uv, r_px, seen, camera.height, camera.width)
            out[k] = disagreement(cov > 0, mask_np, radius, sigma_px=sigma, observed_near=mask_near,
                                  observed_blurred=mask_blur)
            if isinstance(self.trackers[k], OpenLoop) or not bool(seen.any()):
                continue
            typical = float(r_px[seen].median())
            obs = Observation(camera, mask, xk, vk, uv, depth, seen, cov, typical, self.models[k], poses)
            corr = self.trackers[k].correct(obs)
            if corr is None:
                continue
            sel = seen.nonzero().squeeze(1)
            moved = collide_move(self.models[k], xk[sel], corr.dx[sel].to(xk), poses, poses)
            new_x[idx[sel]] = moved + shift[k]
            if corr.dv is not None:
                new_v[idx[sel]] = vk[sel] + corr.dv[sel].to(vk)
            changed = True
        if changed:
            self.state = dataclasses.replace(s, x=new_x, v=new_v)
        return out
