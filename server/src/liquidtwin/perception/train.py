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

Training length chosen on held-out pours (``select_every`` > 0, ``select_on``): every
``select_every`` steps the network is scored on pours it does not train on (the dataset's
calibration split: fresh pours of the training containers) by the area under the 0 px
precision–recall curve, and the best-scoring weights are the ones returned. The longest
schedule is then a budget, not a choice: no one length suits every input (at 10× the grid's
steps the RGB and grey networks gain on unseen containers while the flow-fused ones overfit).
``watch`` clips are scored at the same checkpoints for the record only; they never choose.
"""

from __future__ import annotations

import copy
import time
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from .data import Clip
from .inputs import INPUTS, FrameEncoder, parse_augment
from .metrics import auc
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
    select_every: int = 0       # score on held-out pours every this many steps, keep the best (0: off)
    augment: str = ""           # "flip", "colour" or "flip,colour": see augment_window (empty: none)


def augment_window(rng, x: np.ndarray, y: np.ndarray, input_type: str, augment: str):
    """One training window's augmentation, the same for all its frames: x (T, C, h, w) inputs,
    y (T, h, w) masks; returns new arrays.

    - ``flip``: mirror left–right with probability ½. The mirror image of a pour is a pour
      (the physics has no handedness; gravity has a direction, so never up–down). The
      flow's angle θ = atan2(dy, dx) becomes π − θ: its cosine plane changes sign where
      there is flow (zero flow keeps the encoder's sin 0, cos 1).
    - ``colour``: the image planes only (not flow): each channel scaled by U(0.7, 1.3) and
      shifted by U(−0.1, 0.1), clipped to [0, 1]; RGB channels also put in a random order.
      Water takes its look from what is behind it, so a detector should not key on the
      training containers' colours.
    """
    groups = INPUTS[input_type]
    n_image = 0 if input_type == "flow" else groups[0]
    if "flip" in augment and rng.random() < 0.5:
        x, y = x[..., ::-1].copy(), y[..., ::-1].copy()
        if "flow" in input_type:
            cos, mag = n_image + 1, n_image + 2
            x[:, cos] = np.where(x[:, mag] > 0, -x[:, cos], x[:, cos])
    if "colour" in augment and n_image:
        img = x[:, :n_image]
        if n_image == 3:
            img = img[:, rng.permutation(3)]
        gain = rng.uniform(0.7, 1.3, n_image).astype(np.float32)[None, :, None, None]
        shift = rng.uniform(-0.1, 0.1, n_image).astype(np.float32)[None, :, None, None]
        x = x.copy()
        x[:, :n_image] = np.clip(img * gain + shift, 0.0, 1.0)
    return x, y


def encode_clips(clips: list[Clip], input_type: str) -> list[np.ndarray]:
    """(T, C, H, W) float32 network inputs per clip."""
    enc = FrameEncoder(input_type)
    return [enc.sequence(c.frames) for c in clips]


def weighted_bce(logits: torch.Tensor, truth: torch.Tensor, negative_weight: float = 0.1) -> torch.Tensor:
    """Mean BCE with not-liquid pixels weighted ``negative_weight``."""
    w = torch.where(truth > 0.5, 1.0, negative_weight)
    return F.binary_cross_entropy_with_logits(logits, truth, weight=w)


def _sample(rng, inputs, clips, cfg: TrainConfig, crop: bool, aug_rng=None):
    """One batch: x (B, T, C, h, w), y (B, T, 1, h, w). Augmentation draws from its own
    ``aug_rng``, so the windows and crops are those of the same seed without it."""
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
        if cfg.augment:
            x, y = augment_window(aug_rng, x, y, cfg.input_type, cfg.augment)
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


def train(clips: list[Clip], cfg: TrainConfig = TrainConfig(), *, progress: bool = True, init=None,
          select_on: list[Clip] | None = None, watch: list[Clip] | None = None):
    """Train a detector on ``clips`` (fresh, or its input block started from the trained
    detector ``init``); returns (net in eval mode, info dict).

    With ``cfg.select_every`` > 0 the weights returned are those of the checkpoint (every
    ``select_every`` steps and the last) with the highest 0 px AUC on ``select_on``; the
    curve is ``info["checkpoints"]`` (step, ``select_auc`` and, when given, ``watch_auc``
    on ``watch``, which never chooses) and the choice ``info["selected_step"]``."""
    if not clips:
        raise ValueError("no training clips")
    if cfg.select_every < 0:
        raise ValueError(f"select_every must be >= 0, got {cfg.select_every}")
    if cfg.select_every and not select_on:
        raise ValueError("select_every > 0 needs held-out pours to choose on (select_on: the dataset's "
                         "calibration split; add one with `liquidtwin perception data --calib 3`)")
    if parse_augment(cfg.augment) != cfg.augment:
        raise ValueError(f"augment must be one of '', 'flip', 'colour', 'flip,colour'; got {cfg.augment!r}")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    aug_rng = np.random.default_rng([cfg.seed, 1])
    net = build_model(cfg.kind, cfg.input_type, cfg.fusion)
    if init is not None:
        init_encoder(net, init)
    inputs = encode_clips(clips, cfg.input_type)
    scorers = {}
    if cfg.select_every:
        scorers["select_auc"] = _Scorer(select_on, cfg.input_type)
        if watch:
            scorers["watch_auc"] = _Scorer(watch, cfg.input_type)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    total = cfg.crop_iterations + cfg.full_iterations
    history, checkpoints, best, t0 = [], [], None, time.perf_counter()
    bar = tqdm(range(total), desc=f"train {cfg.kind}/{cfg.input_type}/{cfg.fusion}", disable=not progress,
               leave=False)
    net.train()
    for it in bar:
        x, y = _sample(rng, inputs, clips, cfg, crop=it < cfg.crop_iterations, aug_rng=aug_rng)
        loss = weighted_bce(net(x), y, cfg.negative_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        history.append(float(loss.detach()))
        if it % 10 == 0:
            bar.set_postfix(loss=f"{np.mean(history[-10:]):.4f}")
        step = it + 1
        if scorers and (step % cfg.select_every == 0 or step == total):
            net.eval()
            point = {"step": step, **{k: sc(net) for k, sc in scorers.items()}}
            net.train()
            checkpoints.append(point)
            if best is None or point["select_auc"] > best[0]["select_auc"]:
                best = (point, copy.deepcopy(net.state_dict()))
            bar.set_postfix(loss=f"{np.mean(history[-10:]):.4f}", held_out=f"{point['select_auc']:.3f}")
    info = {"config": asdict(cfg), "wall_s": time.perf_counter() - t0, "loss_history": history,
            "clips": [c.name for c in clips]}
    if best is not None:
        net.load_state_dict(best[1])
        info.update(checkpoints=checkpoints, selected_step=best[0]["step"],
                    selected_on=[c.name for c in select_on])
    return net.eval(), info


class _Scorer:
    """0 px PR AUC of a network over fixed clips, their inputs encoded once."""

    def __init__(self, clips: list[Clip], input_type: str):
        self.inputs = encode_clips(clips, input_type)
        self.truth = np.concatenate([c.masks for c in clips])

    def __call__(self, net) -> float:
        return auc(np.concatenate([detect(net, x) for x in self.inputs]), self.truth, 0)


@torch.no_grad()
def detect(net, inputs: np.ndarray) -> np.ndarray:
    """(T, H, W) float32 liquid probabilities for one clip's (T, C, H, W) inputs."""
    return torch.sigmoid(net(torch.from_numpy(inputs)[None]))[0, :, 0].numpy()
