"""SOLVEPERCEPTION (thesis §8.4.2, Fig. 8.8, SPEC §4.4) as a differentiable layer.

Given the particles x (N, 3), a camera, which particles it sees and the observed liquid mask:

1. the **observed** distance field D_o: each pixel's distance to the nearest observed liquid
   pixel (OpenCV ``distanceTransform``, exact Euclidean), and from it, with a fixed 2-D
   convolution (central differences), the field F_o = −½ ∇(D_o²): the vector, px, from each
   pixel to its nearest liquid pixel (exact wherever the pixel and its 4 neighbours share
   that nearest pixel; 0 on liquid);
2. the **model labels**: the visible particles drawn as their projected spheres (as the
   session draws the model mask); the **disparity** image = observed − model labels
   (+1 liquid the model misses, −1 model where no liquid is seen, 0 agreement) and the
   disparity field F_d: the same vector field toward the nearest *uncovered* liquid pixel
   (observed and not drawn by the model);
   Uncovered regions thinner than :data:`NOISE_PX` are left out of F_d (a morphological
   opening): a mask's ragged edge and specks leave one- or two-pixel slivers of "liquid the
   model misses" around every agreeing blob, and F_d, which has no range limit, dragged
   every visible particle towards the nearest sliver;
3. the blending net (:class:`BlendNet`, 4 convolutions, ReLU after the first three, a
   sigmoid) turns the disparity image into a per-pixel weight b ∈ (0, 1); the blended field
   F = b·F_o + (1 − b)·F_d;
4. F is read at each visible particle's projection (bilinear), scaled by the net's learned
   gain and lifted back into 3-D parallel to the image plane (× depth / focal length): ΔP.
   Moves are capped at ``max_move`` m per call. Occluded and out-of-view particles get 0.

No particles × pixels loop: the fields are whole-image operations (on the window that holds
the liquid and the particles, which gives the same values at the particles), the read-out is
one bilinear gather. Differentiable w.r.t. x (through the projection, the read-out and the
lift) and the net's weights; the labels and distance transforms are piecewise constant in x.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..camera import Camera, sphere_coverage, sphere_radius_px
from .warp import image_scale, lift, sample_bilinear

#: The shipped blending-net weights (``python -m liquidtwin.tracking.train_perception``).
WEIGHTS = Path(__file__).resolve().parent.parent / "data" / "perception_blend.pt"
#: Smallest drawn sphere radius, px (the session's MIN_RADIUS_PX).
MIN_RADIUS_PX = 1.0
#: Receptive radius of :class:`BlendNet`, px (dilations 1 + 2 + 4 + 1).
_RECEPTIVE_PX = 8
#: Width, px at 640×480 (scaled with the image like the warp field's ℓ), of the opening that
#: keeps mask noise out of the disparity field F_d: uncovered liquid thinner than this does not
#: pull. The shipped blend net puts b ≈ 0 (1e-4 on agreement, 1e-13 on disparity), so F ≈ F_d
#: everywhere and, without the opening, a settled pool that the model already matched was
#: spread towards its ragged edges (full 60 % hold pour at 4.4 s: IOU 0.78 open loop, 0.59 with
#: perception before the opening, 0.74 with it; ``python bench/tracking_frames.py REC --every 5
#: --blend``, README).
NOISE_PX = 5.0


def open_mask(mask: torch.Tensor, width_px: float) -> torch.Tensor:
    """``mask`` (H, W) bool without the parts thinner than ``width_px`` (morphological opening
    with a disc of that diameter, rounded to the nearest odd pixel count; < 3 px: unchanged)."""
    k = 2 * int(round((width_px - 1.0) / 2.0)) + 1
    if k < 3 or not bool(mask.any()):
        return mask
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    out = cv2.morphologyEx(mask.cpu().numpy().astype(np.uint8), cv2.MORPH_OPEN, disc)
    return torch.from_numpy(out > 0).to(mask.device)


class PerceptionWeightsError(ValueError):
    """The blending-net weights file is missing, corrupt or for another architecture."""


class BlendNet(nn.Module):
    """The per-pixel blending net: disparity image (B, 1, H, W) → blend b (B, 1, H, W) in (0, 1).

    Four 3×3 convolutions (1 → c → c → c → 1, dilations 1, 2, 4, 1: a 17 px receptive field),
    ReLU after the first three, then a sigmoid. ``log_gain`` (scalar parameter): the read-out
    field (px) is multiplied by exp(log_gain) before the lift (a fraction of the way to the
    nearest liquid per solver iteration). ``channels`` = 8: 1,322 parameters.
    """

    def __init__(self, channels: int = 8):
        super().__init__()
        c = int(channels)
        self.convs = nn.ModuleList([nn.Conv2d(1, c, 3, padding=1), nn.Conv2d(c, c, 3, padding=2, dilation=2),
                                    nn.Conv2d(c, c, 3, padding=4, dilation=4), nn.Conv2d(c, 1, 3, padding=1)])
        self.log_gain = nn.Parameter(torch.tensor(math.log(0.1)))

    def forward(self, disparity: torch.Tensor) -> torch.Tensor:
        y = disparity
        for k, conv in enumerate(self.convs):
            y = conv(y)
            if k < 3:
                y = F.relu(y)
        return torch.sigmoid(y)

    @property
    def gain(self) -> torch.Tensor:
        return self.log_gain.exp()


def load_blend_net(path=None, *, dtype=torch.float32) -> BlendNet:
    """The blending net with weights from ``path`` (default: the shipped :data:`WEIGHTS`), a
    plain state_dict loaded with ``torch.load(weights_only=True)``. Raises
    :class:`PerceptionWeightsError` for a missing, corrupt or mismatched file."""
    path = Path(WEIGHTS if path is None else path)
    if not path.is_file():
        raise PerceptionWeightsError(f"perception blending-net weights not found at {path}; train them with "
                                     f"python -m liquidtwin.tracking.train_perception --out {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unpickling failure means an unusable file
        raise PerceptionWeightsError(f"{path} is not a readable torch state_dict ({type(e).__name__}: {e}); "
                                     f"re-train it with python -m liquidtwin.tracking.train_perception") from e
    if not isinstance(state, dict):
        raise PerceptionWeightsError(f"{path} holds a {type(state).__name__}, expected a state_dict")
    channels = state.get("convs.0.weight", torch.zeros(8)).shape[0]
    net = BlendNet(channels)
    try:
        net.load_state_dict(state)
    except (RuntimeError, KeyError) as e:
        raise PerceptionWeightsError(f"{path} does not match the blending net (4 convolutions, "
                                     f"{channels} channels): {e}") from e
    if not all(bool(torch.isfinite(p).all()) for p in net.parameters()):
        raise PerceptionWeightsError(f"{path} contains NaN or inf weights")
    return net.to(dtype).eval()


def _check_mask(mask, what: str) -> torch.Tensor:
    mask = torch.as_tensor(mask)
    if mask.dim() != 2:
        raise ValueError(f"{what} must be an (H, W) image, got shape {tuple(mask.shape)}")
    return mask if mask.dtype == torch.bool else mask != 0


def _squared_distance(mask: torch.Tensor) -> torch.Tensor | None:
    """(H, W) float64 squared Euclidean distance, px², from each pixel centre to the nearest True
    pixel of ``mask`` (H, W) bool — exact integers; None when the mask is empty."""
    if not bool(mask.any()):
        return None
    free = (~mask).cpu().numpy().astype(np.uint8)
    d = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    # Distances between pixel centres are square roots of integers. OpenCV's float32 answer is
    # off by about an ulp, and *which* ulp depends on where its buffers fall in memory: the same
    # mask gave two answers on alternate calls (opencv 5.0.0), so SPNets+perception replays of
    # one recording parted within a process. D² rounded to its integer is exact and reproducible
    # (an ulp of error moves D² by 2·D·ulp(D) < 0.1 up to D = 800 px).
    return torch.from_numpy(np.rint(d.astype(np.float64) ** 2)).to(mask.device)


def distance_field(mask) -> torch.Tensor:
    """(H, W) float32 Euclidean distance, px, from each pixel centre to the nearest True pixel
    of ``mask`` (H, W) bool (0 on it); +inf everywhere when the mask is empty."""
    mask = _check_mask(mask, "mask")
    d2 = _squared_distance(mask)
    if d2 is None:
        return torch.full(mask.shape, math.inf, dtype=torch.float32, device=mask.device)
    return d2.sqrt().to(torch.float32)


_DIFF = torch.tensor([[[[0.0, 0.0, 0.0], [0.25, 0.0, -0.25], [0.0, 0.0, 0.0]]],
                      [[[0.0, 0.25, 0.0], [0.0, 0.0, 0.0], [0.0, -0.25, 0.0]]]])


def nearest_vectors(mask, dtype=torch.float32) -> torch.Tensor:
    """(2, H, W) (du, dv) px from each pixel to its nearest True pixel of ``mask`` (H, W):
    F = −½ ∇(D²) with a fixed central-difference convolution (replicate-padded border) of
    the squared distance field. Zero when the mask is empty."""
    mask = _check_mask(mask, "mask")
    d2 = _squared_distance(mask)
    if d2 is None:
        return torch.zeros((2,) + tuple(mask.shape), dtype=dtype, device=mask.device)
    d2 = F.pad(d2[None, None], (1, 1, 1, 1), mode="replicate")
    # conv2d correlates: [¼, 0, −¼] gives ¼(D²(p−1) − D²(p+1)) = −½ ∂D²/∂u (central difference).
    g = F.conv2d(d2, _DIFF.to(d2))[0]
    return g.to(dtype)


def model_labels(camera: Camera, uv: torch.Tensor, depth: torch.Tensor, visible: torch.Tensor,
                 radius_m: float) -> torch.Tensor:
    """(H, W) bool model mask: visible particles drawn as their projected spheres of radius
    ``radius_m`` m (uv (N, 2) px, depth (N,) m, visible (N,) bool)."""
    r = sphere_radius_px(camera.fx, depth.detach(), radius_m, min_px=MIN_RADIUS_PX)
    return sphere_coverage(uv.detach(), r, visible, camera.height, camera.width) > 0


def _crop(observed: torch.Tensor, uv: torch.Tensor, r_max: float, H: int, W: int):
    """The image window (rows r0:r1, columns c0:c1) holding all observed liquid and every
    drawn particle, grown by the net's receptive radius: inside it every field value at a
    particle equals the full image's (all liquid lies in it, and the zero padding of the
    net's layers at its border is more than the receptive radius away from any particle).
    Returns the window and uv shifted into it."""
    m = _RECEPTIVE_PX + int(math.ceil(r_max)) + 2
    rows, cols = observed.any(1).nonzero(), observed.any(0).nonzero()
    lo = torch.minimum(uv.min(0).values, torch.stack([cols.min(), rows.min()]).to(uv))
    hi = torch.maximum(uv.max(0).values, torch.stack([cols.max(), rows.max()]).to(uv))
    c0, r0 = max(int(math.floor(float(lo[0]))) - m, 0), max(int(math.floor(float(lo[1]))) - m, 0)
    c1, r1 = min(int(math.ceil(float(hi[0]))) + m + 1, W), min(int(math.ceil(float(hi[1]))) + m + 1, H)
    return (r0, r1, c0, c1), uv - torch.tensor([c0, r0], dtype=uv.dtype, device=uv.device)


def blended_field(x: torch.Tensor, camera: Camera, visible: torch.Tensor, observed: torch.Tensor, net: BlendNet,
                  *, radius_m: float, observed_field: torch.Tensor | None = None):
    """Steps 1–3 of the module doc: the blended field F (2, h, w), px, on the window
    (:func:`_crop`) that holds the liquid and the visible particles, and the window's origin
    (2,) (u, v) px. Arguments as :func:`solve_perception`; ``visible`` must not be empty and
    ``observed`` must show liquid. Differentiable w.r.t. the net's weights."""
    uv, depth = camera.project(x.detach())
    idx = visible.nonzero().squeeze(1)
    r = sphere_radius_px(camera.fx, depth[idx], radius_m, min_px=MIN_RADIUS_PX)
    (r0, r1, c0, c1), uv_c = _crop(observed, uv[idx], float(r.max()), camera.height, camera.width)
    obs_c = observed[r0:r1, c0:c1]
    model = sphere_coverage(uv_c, r, None, r1 - r0, c1 - c0) > 0
    f_obs = nearest_vectors(obs_c, x.dtype) if observed_field is None else observed_field[:, r0:r1, c0:c1].to(x)
    f_dis = nearest_vectors(open_mask(obs_c & ~model, NOISE_PX * image_scale(camera.height, camera.width)), x.dtype)
    disparity = (obs_c.to(x.dtype) - model.to(x.dtype))[None, None]
    b = net(disparity.to(net.log_gain.dtype))[0].to(x.dtype)          # (1, h, w)
    return b * f_obs + (1.0 - b) * f_dis, torch.tensor([c0, r0], dtype=x.dtype, device=x.device)


def apply_field(field: torch.Tensor, origin: torch.Tensor, x: torch.Tensor, camera: Camera, visible: torch.Tensor,
                gain: torch.Tensor, *, max_move: float | None = None) -> torch.Tensor:
    """Step 4 of the module doc: ``field`` (2, h, w) px with window ``origin`` (2,) px read at
    the visible particles' projections, × ``gain``, lifted to 3-D and capped at ``max_move``
    m → ΔP (N, 3) m (0 for invisible rows). Differentiable w.r.t. x, field and gain."""
    idx = visible.nonzero().squeeze(1)
    uv, depth = camera.project(x[idx])
    duv = sample_bilinear(field, uv - origin.to(uv)) * gain.to(x.dtype)
    d3 = lift(camera, duv, depth)
    if max_move is not None:
        norm = d3.norm(dim=1, keepdim=True)
        d3 = d3 * torch.clamp(float(max_move) / norm.clamp(min=1e-12), max=1.0)
    return torch.zeros_like(x).index_put((idx,), d3)


def _check_inputs(x, camera, visible, observed):
    if x.dim() != 2 or x.shape[1] != 3:
        raise ValueError(f"particle positions must be (N, 3) m, got {tuple(x.shape)}")
    observed = _check_mask(observed, "observed mask").to(x.device)
    if tuple(observed.shape) != (camera.height, camera.width):
        raise ValueError(f"observed mask is {tuple(observed.shape)}, the camera is {(camera.height, camera.width)} "
                         f"(H, W)")
    visible = torch.as_tensor(visible, device=x.device)
    if visible.shape != (x.shape[0],) or visible.dtype != torch.bool:
        raise ValueError(f"visible must be (N,) bool for N = {x.shape[0]}, got {tuple(visible.shape)} {visible.dtype}")
    return visible, observed


def solve_perception(x: torch.Tensor, camera: Camera, visible: torch.Tensor, observed: torch.Tensor, net: BlendNet,
                     *, radius_m: float, max_move: float | None = None,
                     observed_field: torch.Tensor | None = None) -> torch.Tensor:
    """ΔP (N, 3) m: the move of each particle toward the observed liquid (module doc).

    Args:
      x: (N, 3) particle positions, m, world (may require grad).
      camera: the calibrated camera (H × W px).
      visible: (N,) bool, the particles the camera sees (not occluded, in the image).
      observed: (H, W) bool observed liquid mask.
      net: the :class:`BlendNet`.
      radius_m: particle radius drawn for the model labels, m.
      max_move: cap on a particle's move, m (None: uncapped).
      observed_field: :func:`nearest_vectors` of ``observed`` if already computed (2, H, W).
    Returns:
      (N, 3) in x's dtype; rows of invisible particles are 0.
    """
    visible, observed = _check_inputs(x, camera, visible, observed)
    if not bool(visible.any()) or not bool(observed.any()):
        return torch.zeros_like(x) + 0.0 * x  # keep the graph (zero gradient) for callers that backpropagate
    field, origin = blended_field(x, camera, visible, observed, net, radius_m=radius_m, observed_field=observed_field)
    return apply_field(field, origin, x, camera, visible, net.gain, max_move=max_move)
