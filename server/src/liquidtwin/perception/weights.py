"""Detector model files: ``{"format", "meta", "state_dict"}`` written by ``torch.save`` and
read back with ``torch.load(weights_only=True)`` — tensors and plain data only, no pickle
of code. ``meta`` holds everything needed to rebuild the network (kind, input type, fusion,
constructor arguments, network resolution) plus how it was trained.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from .nets import KINDS, build_model

FORMAT = "liquidtwin.perception.v1"
DEFAULT_MODEL = Path(__file__).resolve().parent.parent / "data" / "detector.pt"


class PerceptionModelError(ValueError):
    """A detector model file is missing, corrupt, or does not match its network."""


def save_model(path, net: torch.nn.Module, meta: dict | None = None) -> Path:
    """Write ``net`` with its build arguments and ``meta`` (JSON-able) to ``path``."""
    info = {"kind": net.kind, "input_type": net.input_type, "fusion": net.fusion, "kwargs": {}}
    if hasattr(net, "frames"):
        info["kwargs"]["frames"] = net.frames
    info.update(meta or {})
    json.dumps(info)     # raises now, not at load time, if meta is not plain data
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sd = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    torch.save({"format": FORMAT, "meta": json.dumps(info), "state_dict": sd}, path)
    return path


def load_model(path=None, *, map_location: str = "cpu") -> tuple[torch.nn.Module, dict]:
    """(network in eval mode, meta) from a model file (default: the shipped detector)."""
    path = Path(DEFAULT_MODEL if path is None else path)
    if not path.is_file():
        raise PerceptionModelError(f"no detector model file at {path}")
    try:
        blob = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as e:    # torch raises several types for truncated / foreign files
        raise PerceptionModelError(f"{path} is not a readable detector model file: {e}") from e
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        raise PerceptionModelError(f"{path} is not a {FORMAT} model file")
    try:
        meta = json.loads(blob["meta"])
        kind, input_type, fusion = meta["kind"], meta["input_type"], meta["fusion"]
    except (KeyError, TypeError, ValueError) as e:
        raise PerceptionModelError(f"{path}: model metadata unreadable ({e})") from e
    if kind not in KINDS:
        raise PerceptionModelError(f"{path}: unknown detector kind {kind!r} (known: {KINDS})")
    try:
        net = build_model(kind, input_type, fusion, **meta.get("kwargs", {}))
        net.load_state_dict(blob["state_dict"])
    except (ValueError, RuntimeError, TypeError, KeyError) as e:
        raise PerceptionModelError(f"{path}: weights do not match a {kind}/{input_type}/{fusion} "
                                   f"detector: {e}") from e
    return net.eval(), meta
