"""Detector model files: ``{"format", "meta", "state_dict"}`` written by ``torch.save`` and
read back with ``torch.load(weights_only=True)`` — tensors and plain data only, no pickle
of code. ``meta`` holds everything needed to rebuild the network (kind, input type, fusion,
constructor arguments, network resolution) plus how it was trained.
"""

from __future__ import annotations

from pathlib import Path

import torch

from .. import _weights
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
    return _weights.write(path, FORMAT, net, info)


def load_model(path=None, *, map_location: str = "cpu") -> tuple[torch.nn.Module, dict]:
    """(network in eval mode, meta) from a model file (default: the shipped detector)."""
    path = Path(DEFAULT_MODEL if path is None else path)
    meta, state_dict = _weights.read(path, FORMAT, PerceptionModelError, "detector model", map_location)
    try:
        kind, input_type, fusion = meta["kind"], meta["input_type"], meta["fusion"]
    except KeyError as e:
        raise PerceptionModelError(f"{path}: model metadata unreadable ({e})") from e
    if kind not in KINDS:
        raise PerceptionModelError(f"{path}: unknown detector kind {kind!r} (known: {KINDS})")
    try:
        net = build_model(kind, input_type, fusion, **meta.get("kwargs", {}))
        net.load_state_dict(state_dict)
    except (ValueError, RuntimeError, TypeError, KeyError) as e:
        raise PerceptionModelError(f"{path}: weights do not match a {kind}/{input_type}/{fusion} "
                                   f"detector: {e}") from e
    return net.eval(), meta
