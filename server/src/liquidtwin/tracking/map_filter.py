"""MAP-filter tracking (thesis §7.2.2, SPEC §4.2): each visible particle jumps to the best of
27 nearby hypotheses.

Per visible particle i, the hypotheses are its predicted position x_i plus the offsets of a
3 × 3 × 3 grid of ``cell_m`` cells (5 mm in the thesis), centre included. With a uniform prior
over the feasible ones, the MAP hypothesis maximises the activation::

    Ψ(x̃) = Σ_{j ∈ liquid(I)} W(|x̂̃ − j|) / (Φ(j) + 1)

x̂̃ the hypothesis projected into the image, W(d) = exp(−d²/ℓ²) for d ≤ r_c (ℓ = 33 px,
r_c = 100 px at 640×480, scaled like the warp field: :func:`~.warp.image_scale`), Φ the
coverage of pixel j by the visible particles' discs (the particle's own included, as in the
thesis). Ψ is computed once per frame as one image, the FFT cross-correlation of
g = mask / (Φ + 1) with W (:func:`psi_image`, normalised by Σ W), and read at each
hypothesis's projection (bilinear).

Feasible hypotheses: in front of the camera, projecting into the image, and not inside an
object nor reached through one (the SDF of every object is ≥ 0 along the straight move,
sampled finer than half the thinnest wall). The predicted position itself is always allowed
(the simulator put it there; the engine keeps particles out of objects).

Choice: the argmax of Ψ, except that hypotheses within ``min_gain`` (normalised Ψ) of the best
count as ties and the shortest move among them wins (the centre when it is one of them: far
from liquid nothing moves). Without this, near-equal scores — e.g. hypotheses that differ only
along the line of sight, which the image cannot tell apart — make every visible particle
jump every frame and stir the liquid (see the defaults below).

The correction is dx = chosen − predicted and, as the thesis adjusts the velocity to the
change of position, dv = dx / ``velocity_time_s`` (a camera period) × ``velocity_share``.
Occluded particles are left alone.
"""

from __future__ import annotations

import math

import torch

from ..camera import sphere_coverage, sphere_radius_px
from ..sim import min_sdf, particle_radius
from ._fft import correlate
from .base import Correction, Observation, Tracker
from .warp import CUTOFF_PX, LENGTH_PX, image_scale, sample_bilinear

#: Defaults, chosen on the two golden pours (mean IOU over frames with liquid, 5 px discs;
#: open loop 0.218 / 0.182, warp field 0.233 / 0.209) among cells 2–10 mm, velocity shares
#: 0–1 and minimum gains 1e-5–1e-2, subject to keeping a fully seen, gently rocked bowl of
#: 1.7k particles calm (tests/server/test_tracking_map.py). The thesis's 5 mm cell with its
#: velocity rule (share 1) and no minimum gain makes ~every visible particle jump 5–9 mm every
#: frame at h = 11 mm: IOU 0.15 / 0.11 and liquid thrown out of the bowl at 3–4 m/s. With these
#: defaults: IOU 0.211 / 0.196 (on par with open loop), bowl calm (0.26 m/s fastest, none lost).
#: Grid cell of the hypotheses, m (thesis: 5 mm).
DEFAULT_CELL_M = 0.0025
#: Share of dx / camera period added to the velocity (0: the jump only; 0.2 already stirs the bowl).
DEFAULT_VELOCITY_SHARE = 0.0
#: A hypothesis is only preferred to a shorter move if its normalised Ψ is higher by more than
#: this (the float32 FFT's rounding is ~1e-7; W at the cut-off is ~1e-4 of its peak).
DEFAULT_MIN_GAIN = 3e-3
#: Hypothesis rounds per observation (each from the last round's choice, Φ redrawn). On the
#: quick pouring benchmark's tuning cases (base seed 100, trial 0, 7 cases; projected-sphere
#: model mask) one round scores 0.187 (open loop 0.145), three rounds 0.121 and lose liquid.
DEFAULT_ITERATIONS = 1


def se_kernel(length_px: float, cutoff_px: float, dtype=torch.float64, device=None) -> torch.Tensor:
    """(1, 2R+1, 2R+1) scalar kernel, R = ⌊cutoff⌋: entry [0, R+dy, R+dx] = exp(−|d|²/ℓ²) for
    |d| ≤ cutoff (d = 0 included), else 0 (offsets d = pixel − hypothesis, px)."""
    if not (length_px > 0 and cutoff_px >= 1):
        raise ValueError(f"need length_px > 0 and cutoff_px >= 1, got {length_px}, {cutoff_px}")
    R = int(math.floor(cutoff_px))
    d = torch.arange(-R, R + 1, dtype=dtype, device=device)
    r2 = d[:, None] ** 2 + d[None, :] ** 2
    return torch.where(r2 <= cutoff_px * cutoff_px, torch.exp(-r2 / (length_px * length_px)), 0.0)[None]


def psi_image(weights: torch.Tensor, length_px: float, cutoff_px: float) -> torch.Tensor:
    """Ψ(p) = Σ_j weights(j) · W(|j − p|) at every pixel centre p: weights (H, W) float
    (mask / (Φ + 1)) → (H, W), weights' dtype and device (not normalised)."""
    return correlate(weights, se_kernel, float(length_px), float(cutoff_px))[0]


def hypothesis_offsets(cell_m: float, dtype=torch.float64, device=None) -> torch.Tensor:
    """(27, 3) offsets, m, of the 3 × 3 × 3 grid; row 13 is the centre (0, 0, 0)."""
    g = torch.tensor([-1.0, 0.0, 1.0], dtype=dtype, device=device) * cell_m
    return torch.stack(torch.meshgrid(g, g, g, indexing="ij"), -1).reshape(27, 3)


CENTRE = 13


class MapFilter(Tracker):
    """MAP-filter tracker (module doc).

    Args:
      cell_m: hypothesis grid cell, m (default :data:`DEFAULT_CELL_M`; thesis 5 mm).
      length_px, cutoff_px: W's length scale and cut-off at 640×480, px (scaled with the image).
      velocity_share: dv = dx / velocity_time_s × this (0: position only).
      velocity_time_s: the camera period, s.
      min_gain: normalised-Ψ margin within which hypotheses tie (the shortest move wins).
      iterations: rounds of hypotheses per observation; each starts from the previous round's
        choice with the coverage Φ redrawn there (projected spheres, as the engine draws), so a
        particle may travel up to ``iterations`` cells per frame.
    """

    name = "map_filter"

    def __init__(self, cell_m: float = DEFAULT_CELL_M, *, length_px: float = LENGTH_PX, cutoff_px: float = CUTOFF_PX,
                 velocity_share: float = DEFAULT_VELOCITY_SHARE, velocity_time_s: float = 1.0 / 30.0,
                 min_gain: float = DEFAULT_MIN_GAIN, iterations: int = DEFAULT_ITERATIONS):
        if isinstance(iterations, bool) or int(iterations) != iterations or iterations < 1:
            raise ValueError(f"MAP filter iterations must be a whole number >= 1, got {iterations!r}")
        for k, v in (("cell_m", cell_m), ("length_px", length_px), ("cutoff_px", cutoff_px),
                     ("velocity_time_s", velocity_time_s)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"MAP filter {k} must be a positive number, got {v}")
        for k, v in (("velocity_share", velocity_share), ("min_gain", min_gain)):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"MAP filter {k} must be >= 0, got {v}")
        self.cell_m, self.length_px, self.cutoff_px = float(cell_m), float(length_px), float(cutoff_px)
        self.velocity_share, self.velocity_time_s = float(velocity_share), float(velocity_time_s)
        self.min_gain, self.iterations = float(min_gain), int(iterations)

    def psi(self, mask: torch.Tensor, coverage: torch.Tensor) -> torch.Tensor:
        """(H, W) activation Ψ of an observation normalised by Σ_d W (0 far from liquid, 1 in
        the middle of a large uncovered liquid region): mask (H, W) bool, coverage (H, W) int."""
        H, W = mask.shape
        s = image_scale(H, W)
        ell, cut = self.length_px * s, max(self.cutoff_px * s, 1.0)
        g = mask.to(torch.float32) / (coverage.to(torch.float32) + 1.0)
        return psi_image(g, ell, cut) / float(se_kernel(ell, cut).sum())

    def scores(self, obs: Observation, vis: torch.Tensor, x: torch.Tensor | None = None,
               coverage: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Hypotheses around the visible particles ``vis`` (K,) → (hypotheses (K, 27, 3) m,
        normalised Ψ (K, 27) with −inf where infeasible). ``x`` (K, 3) m and ``coverage``
        (H, W) replace the observation's positions of those particles and its Φ (iterations)."""
        H, W = obs.mask.shape
        x = obs.x[vis] if x is None else x
        coverage = obs.coverage if coverage is None else coverage
        off = hypothesis_offsets(self.cell_m, x.dtype, x.device)
        hyp = x[:, None, :] + off[None]
        uv, depth = obs.camera.project(hyp.reshape(-1, 3))
        psi = self.psi(obs.mask, coverage)
        score = sample_bilinear(psi[None], uv.to(psi.dtype))[:, 0].reshape(-1, 27).to(x.dtype)
        ok = ((depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1))
        ok = ok.reshape(-1, 27) & self._outside_objects(obs, x, off)
        ok[:, CENTRE] = True
        return hyp, torch.where(ok, score, torch.full_like(score, -math.inf))

    def _outside_objects(self, obs: Observation, x: torch.Tensor, off: torch.Tensor) -> torch.Tensor:
        """(K, 27) bool: the straight move x → x + off stays where every object's SDF ≥ 0."""
        ok = torch.ones(len(x), 27, dtype=torch.bool, device=x.device)
        objects = obs.model.objects
        if not objects or len(x) == 0:
            return ok
        reach = float(off.norm(dim=1).max())
        margin = reach + 2 * max(o.cell for o in objects)        # + interpolation slack of the grids
        near = (min_sdf(x, objects, obs.poses.to(x)) < margin).nonzero().squeeze(1)
        if len(near) == 0:
            return ok
        thin = min(o.thickness for o in objects)
        n = max(1, math.ceil(reach / (0.5 * thin)))
        t = torch.arange(1, n + 1, dtype=x.dtype, device=x.device) / n            # (n,)
        pts = x[near][:, None, None, :] + t[None, None, :, None] * off[None, :, None, :]   # (k, 27, n, 3)
        ok[near] = (min_sdf(pts, objects, obs.poses.to(x)) >= 0).all(-1)
        return ok

    def choose(self, score: torch.Tensor) -> torch.Tensor:
        """(K, 27) scores → (K,) chosen hypothesis: of those within ``min_gain`` of the best,
        the shortest move, then the best score (the centre when it qualifies), so moves the image cannot tell
        apart (e.g. along the line of sight) are not made."""
        top = score.max(dim=1, keepdim=True).values
        length = (torch.arange(27, device=score.device)[:, None] // torch.tensor([9, 3, 1], device=score.device)
                  % 3 - 1).abs().sum(1)                                      # 0 centre, 1 face, 2 edge, 3 corner
        near = score >= top - self.min_gain
        # shortest first, then the higher score: (top − score) / min_gain ∈ [0, 1] within the near set
        key = 2.0 * length[None].to(score.dtype) + (top - score) / max(self.min_gain, 1e-30)
        key = torch.where(near, key, torch.full_like(score, math.inf))
        return key.argmin(dim=1)

    def correct(self, obs: Observation) -> Correction | None:
        vis = obs.visible.nonzero().squeeze(1)
        if len(vis) == 0 or not bool(obs.mask.any()):
            return None
        H, W = obs.mask.shape
        rows = torch.arange(len(vis), device=vis.device)
        x0 = obs.x[vis]
        x, cov, r_px = x0, obs.coverage, None
        for it in range(self.iterations):
            if it > 0:                          # redraw the moved particles as projected spheres
                uv, depth = obs.camera.project(x)
                r_px = sphere_radius_px(obs.camera.fx, depth, particle_radius(float(obs.model.spacing)))
                cov = sphere_coverage(uv, r_px, None, H, W)
            hyp, score = self.scores(obs, vis, x, cov)
            x = hyp[rows, self.choose(score)]
        dx = torch.zeros_like(obs.x)
        dx[vis] = x - x0
        dv = dx * (self.velocity_share / self.velocity_time_s) if self.velocity_share > 0 else None
        return Correction(dx, dv)
