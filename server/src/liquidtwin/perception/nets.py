"""Liquid detection networks (thesis §4.4.3): FCN, multi-frame FCN, LSTM-FCN.

All three share the thesis's layout, scaled down for a 2-core CPU:

* input block: 5 conv(3×3)–ReLU–maxpool layers, the first two pools stride 2, the rest
  stride 1 → ``FEATURES`` × H/4 × W/4. Early fusion concatenates image and flow channels into
  one block; late fusion runs one block per group and concatenates their outputs.
* FCN: input block → two 1×1 conv–ReLU → transposed conv ×4 → logits (B, 1, H, W).
* MF-FCN: the input blocks of the last ``frames`` frames (shared weights) concatenated →
  the FCN head. Streaming keeps the previous frames' block outputs (each frame is encoded
  once); before a stream has ``frames`` frames, the first frame's features fill the window.
* LSTM-FCN: the previous output probability image through 3 conv-pool layers (→ H/4),
  concatenated with the input block's output and fed to a conv-LSTM whose gates are 1×1
  convolutions; its hidden state → 1×1 conv → transposed conv ×4 → logits.

Streaming API, identical for all: ``state = net.initial_state(B, H, W)`` then
``logits, state = net.step(x, state)`` per frame (x: (B, C, H, W), H and W multiples of
4); ``net(seq)`` runs a (B, T, C, H, W) sequence and returns (B, T, 1, H, W) logits.
"""

from __future__ import annotations

import torch
from torch import nn

from .inputs import check_input

FEATURES = 24          # channels out of one input block
_BLOCK = (12, 16, 24, 24, FEATURES)
KINDS = ("fcn", "mf_fcn", "lstm_fcn")


def _conv_pool(c_in: int, c_out: int, stride: int) -> nn.Sequential:
    pool = nn.MaxPool2d(2, 2) if stride == 2 else nn.MaxPool2d(3, 1, padding=1)
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, padding=1), nn.ReLU(inplace=True), pool)


def _input_block(c_in: int) -> nn.Sequential:
    layers, c = [], c_in
    for i, c_out in enumerate(_BLOCK):
        layers.append(_conv_pool(c, c_out, 2 if i < 2 else 1))
        c = c_out
    return nn.Sequential(*layers)


def _head(c_in: int, hidden: int) -> nn.Sequential:
    """1×1 convs and the ×4 transposed convolution back to input resolution."""
    return nn.Sequential(nn.Conv2d(c_in, hidden, 1), nn.ReLU(inplace=True),
                         nn.Conv2d(hidden, hidden, 1), nn.ReLU(inplace=True),
                         nn.ConvTranspose2d(hidden, 1, 8, stride=4, padding=2))


class _Encoder(nn.Module):
    """Input block(s) for one input type and fusion: (B, C, H, W) → (B, F, H/4, W/4)."""

    def __init__(self, input_type: str, fusion: str):
        super().__init__()
        groups = check_input(input_type, fusion)
        self.groups = groups if fusion == "late" and len(groups) > 1 else (sum(groups),)
        self.blocks = nn.ModuleList(_input_block(c) for c in self.groups)
        self.out_channels = FEATURES * len(self.groups)
        self.in_channels = sum(groups)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.ndim != 4 or x.shape[1] != self.in_channels:
            raise ValueError(f"expected input (B, {self.in_channels}, H, W), got {tuple(x.shape)}")
        if x.shape[2] % 4 or x.shape[3] % 4:
            raise ValueError(f"image size {x.shape[3]}×{x.shape[2]} must be a multiple of 4")
        parts = torch.split(x, list(self.groups), dim=1)
        return torch.cat([b(p) for b, p in zip(self.blocks, parts)], dim=1)


class _Detector(nn.Module):
    kind = ""

    def __init__(self, input_type: str = "grey_flow", fusion: str = "early"):
        super().__init__()
        self.input_type, self.fusion = input_type, fusion
        self.encoder = _Encoder(input_type, fusion)

    @property
    def in_channels(self) -> int:
        return self.encoder.in_channels

    def initial_state(self, batch: int, height: int, width: int) -> dict:
        return {}

    def forward(self, seq: torch.Tensor) -> torch.Tensor:
        """(B, T, C, H, W) → (B, T, 1, H, W) logits, the stream started fresh."""
        if seq.ndim != 5:
            raise ValueError(f"expected a (B, T, C, H, W) sequence, got {tuple(seq.shape)}")
        b, t = seq.shape[:2]
        state = self.initial_state(b, seq.shape[3], seq.shape[4])
        out = []
        for k in range(t):
            y, state = self.step(seq[:, k], state)
            out.append(y)
        return torch.stack(out, dim=1)


class FCN(_Detector):
    """Single-frame FCN: no state."""

    kind = "fcn"

    def __init__(self, input_type: str = "grey_flow", fusion: str = "early", hidden: int = 32):
        super().__init__(input_type, fusion)
        self.head = _head(self.encoder.out_channels, hidden)

    def step(self, x: torch.Tensor, state: dict) -> tuple[torch.Tensor, dict]:
        return self.head(self.encoder(x)), state

    def forward(self, seq: torch.Tensor) -> torch.Tensor:
        b, t = seq.shape[:2]
        return self.head(self.encoder(seq.flatten(0, 1))).unflatten(0, (b, t))


class MultiFrameFCN(_Detector):
    """The last ``frames`` frames' input blocks (shared weights) → one FCN head."""

    kind = "mf_fcn"

    def __init__(self, input_type: str = "grey_flow", fusion: str = "early", hidden: int = 32, frames: int = 4):
        super().__init__(input_type, fusion)
        if frames < 2:
            raise ValueError(f"a multi-frame FCN needs frames ≥ 2, got {frames}")
        self.frames = int(frames)
        self.head = _head(self.encoder.out_channels * self.frames, hidden)

    def initial_state(self, batch: int, height: int, width: int) -> dict:
        return {"window": []}

    def step(self, x: torch.Tensor, state: dict) -> tuple[torch.Tensor, dict]:
        f = self.encoder(x)
        window = list(state.get("window", [])) or [f] * (self.frames - 1)
        window = (window + [f])[-self.frames:]
        return self.head(torch.cat(window, dim=1)), {"window": window[1:]}

    def forward(self, seq: torch.Tensor) -> torch.Tensor:
        b, t = seq.shape[:2]
        f = self.encoder(seq.flatten(0, 1)).unflatten(0, (b, t))
        pad = f[:, :1].expand(-1, self.frames - 1, -1, -1, -1)
        f = torch.cat([pad, f], dim=1)
        stacked = torch.cat([f[:, i:i + t] for i in range(self.frames)], dim=2)   # oldest first
        return self.head(stacked.flatten(0, 1)).unflatten(0, (b, t))


class LSTMFCN(_Detector):
    """Conv-LSTM over input-block features and the network's own previous output."""

    kind = "lstm_fcn"

    def __init__(self, input_type: str = "grey_flow", fusion: str = "early", hidden: int = 32):
        super().__init__(input_type, fusion)
        self.hidden = int(hidden)
        self.feedback = nn.Sequential(_conv_pool(1, 8, 2), _conv_pool(8, 8, 2), _conv_pool(8, 8, 1))
        c_in = self.encoder.out_channels + 8 + self.hidden
        self.gates = nn.Conv2d(c_in, 4 * self.hidden, 1)
        self.out = nn.Sequential(nn.Conv2d(self.hidden, self.hidden, 1), nn.ReLU(inplace=True),
                                 nn.ConvTranspose2d(self.hidden, 1, 8, stride=4, padding=2))

    def initial_state(self, batch: int, height: int, width: int) -> dict:
        p = next(self.parameters())
        z = torch.zeros(batch, self.hidden, height // 4, width // 4, dtype=p.dtype, device=p.device)
        prob = torch.zeros(batch, 1, height, width, dtype=p.dtype, device=p.device)
        return {"h": z, "c": z.clone(), "prob": prob}

    def step(self, x: torch.Tensor, state: dict) -> tuple[torch.Tensor, dict]:
        f = self.encoder(x)
        h, c, prob = state["h"], state["c"], state["prob"]
        if h.shape[0] != f.shape[0] or h.shape[2:] != f.shape[2:]:
            raise ValueError(f"state is for {tuple(prob.shape[2:])} images in batches of {h.shape[0]}, "
                             f"got {tuple(x.shape[2:])} in batches of {x.shape[0]}; start a new state")
        i, fg, o, g = self.gates(torch.cat([f, self.feedback(prob), h], dim=1)).chunk(4, dim=1)
        c = torch.sigmoid(fg) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        logits = self.out(h)
        return logits, {"h": h, "c": c, "prob": torch.sigmoid(logits)}


_CLASSES = {c.kind: c for c in (FCN, MultiFrameFCN, LSTMFCN)}


def build_model(kind: str, input_type: str = "grey_flow", fusion: str = "early", **kw) -> _Detector:
    """A fresh detector: ``kind`` in KINDS, ``input_type`` in inputs.INPUTS, fusion early|late."""
    if kind not in _CLASSES:
        raise ValueError(f"unknown detector kind {kind!r}; choose from {KINDS}")
    return _CLASSES[kind](input_type, fusion, **kw)


def parameter_count(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())
