"""Training the detectors (thesis §4.5.1, scaled to a 2-core CPU).

Two phases, as in the thesis: pre-training on crops around liquid (the full frames are
> 98 % dry and a fresh network settles on "nothing is liquid"), then full frames. Every
step takes ``batch`` windows of ``window`` consecutive frames (the same crop through the
window), so the multi-frame and recurrent networks see time; not-liquid pixels weigh
``negative_weight`` = 0.1 in the binary cross-entropy. Adam. Inputs (image and flow planes)
are encoded once per clip up front.

Deviations, for CPU time: the thesis trained 61k + 61k iterations with 32-frame windows at
400×300; we use hundreds of iterations and 6-frame windows at 160×120. As in the thesis, a
recurrent or multi-frame detector may start its input block from a trained FCN (``init``).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from .data import Clip
from .inputs import FrameEncoder
from .nets import build_model


@dataclass(frozen=True)
class TrainConfig:
    kind: str = "lstm_fcn"
    input_type: str = "grey_flow"
    fusion: str = "early"
    crop_iterations: int = 300
    full_iterations: int = 150
    crop_px: int = 64
    window: int = 6
    batch: int = 4
    lr: float = 2e-3
    negative_weight: float = 0.1
    seed: int = 0


def encode_clips(clips: list[Clip], input_type: str) -> list[np.ndarray]:
    """(T, C, H, W) float32 network inputs per clip."""
    enc = FrameEncoder(input_type)
    return [enc.sequence(c.frames) for c in clips]


def weighted_bce(logits: torch.Tensor, truth: torch.Tensor, negative_weight: float = 0.1) -> torch.Tensor:
    """Mean BCE with not-liquid pixels weighted ``negative_weight``."""
    w = torch.where(truth > 0.5, 1.0, negative_weight)
    return F.binary_cross_entropy_with_logits(logits, truth, weight=w)


def _sample(rng, inputs, clips, cfg: TrainConfig, crop: bool):
    """One batch: x (B, T, C, h, w), y (B, T, 1, h, w)."""
    xs, ys = [], []
    for _ in range(cfg.batch):
        while True:
            k = int(rng.integers(len(clips)))
            wet = np.flatnonzero(clips[k].masks.any(axis=(1, 2)))
            t_n = len(clips[k].masks)
            if len(wet) and t_n >= cfg.window:
                break
        # windows end on a frame with liquid (most frames are dry before the pour starts)
        end = int(np.clip(rng.choice(wet), cfg.window - 1, t_n - 1)) + 1
        x, y = inputs[k][end - cfg.window:end], clips[k].masks[end - cfg.window:end]
        if crop:
            c = cfg.crop_px
            ty, tx = np.argwhere(y[-1])[int(rng.integers(int(y[-1].sum())))] if y[-1].any() else (0, 0)
            y0 = int(np.clip(ty - rng.integers(c), 0, y.shape[1] - c))
            x0 = int(np.clip(tx - rng.integers(c), 0, y.shape[2] - c))
            x, y = x[:, :, y0:y0 + c, x0:x0 + c], y[:, y0:y0 + c, x0:x0 + c]
        xs.append(x)
        ys.append(y[:, None])
    return torch.from_numpy(np.stack(xs)), torch.from_numpy(np.stack(ys).astype(np.float32))


def init_encoder(net, trained) -> None:
    """Start ``net``'s input block(s) from a trained detector's (same input type and fusion) —
    the thesis initialises the LSTM-FCN from the trained single-frame FCN."""
    if (trained.input_type, trained.fusion) != (net.input_type, net.fusion):
        raise ValueError(f"cannot initialise a {net.input_type}/{net.fusion} detector from a "
                         f"{trained.input_type}/{trained.fusion} one")
    net.encoder.load_state_dict(trained.encoder.state_dict())


def train(clips: list[Clip], cfg: TrainConfig = TrainConfig(), *, progress: bool = True, init=None):
    """Train a detector on ``clips`` (fresh, or its input block started from the trained
    detector ``init``); returns (net in eval mode, info dict)."""
    if not clips:
        raise ValueError("no training clips")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    net = build_model(cfg.kind, cfg.input_type, cfg.fusion)
    if init is not None:
        init_encoder(net, init)
    inputs = encode_clips(clips, cfg.input_type)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    total = cfg.crop_iterations + cfg.full_iterations
    history, t0 = [], time.perf_counter()
    bar = tqdm(range(total), desc=f"train {cfg.kind}/{cfg.input_type}/{cfg.fusion}", disable=not progress,
               leave=False)
    net.train()
    for it in bar:
        x, y = _sample(rng, inputs, clips, cfg, crop=it < cfg.crop_iterations)
        loss = weighted_bce(net(x), y, cfg.negative_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        history.append(float(loss.detach()))
        if it % 10 == 0:
            bar.set_postfix(loss=f"{np.mean(history[-10:]):.4f}")
    info = {"config": asdict(cfg), "wall_s": time.perf_counter() - t0, "loss_history": history,
            "clips": [c.name for c in clips]}
    return net.eval(), info


@torch.no_grad()
def detect(net, inputs: np.ndarray) -> np.ndarray:
    """(T, H, W) float32 liquid probabilities for one clip's (T, C, H, W) inputs."""
    return torch.sigmoid(net(torch.from_numpy(inputs)[None]))[0, :, 0].numpy()
