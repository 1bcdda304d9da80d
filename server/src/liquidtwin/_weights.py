"""Model files shared by the shipped networks (the liquid detector, the catching policy):
``{"format", "meta", "state_dict"}`` written by ``torch.save`` and read back with
``torch.load(weights_only=True)`` — tensors and plain data only, never pickled code. ``meta``
is a JSON string: what rebuilds the network plus how it was made."""

from __future__ import annotations

import json
from pathlib import Path

import torch


def write(path, fmt: str, net: torch.nn.Module, meta: dict, half: bool = False) -> Path:
    """Write ``net``'s weights (``half``: floating-point ones in half precision; loading
    casts them back to the network's precision) and ``meta`` (plain data; checked now, not
    at load time)."""
    text = json.dumps(meta)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sd = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    if half:
        sd = {k: v.half() if v.is_floating_point() else v for k, v in sd.items()}
    torch.save({"format": fmt, "meta": text, "state_dict": sd}, path)
    return path


def read(path: Path, fmt: str, error: type[Exception], what: str,
         map_location: str = "cpu") -> tuple[dict, dict]:
    """(meta, state_dict) of a ``fmt`` file; ``error`` (saying ``what`` it expected) when the
    file is missing, unreadable, of another format or has unreadable metadata."""
    path = Path(path)
    if not path.is_file():
        raise error(f"no {what} file at {path}")
    try:
        blob = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as e:    # torch raises several types for truncated / foreign files
        raise error(f"{path} is not a readable {what} file: {e}") from e
    if not isinstance(blob, dict) or blob.get("format") != fmt or "state_dict" not in blob:
        raise error(f"{path} is not a {fmt} {what} file")
    try:
        meta = json.loads(blob["meta"])
        if not isinstance(meta, dict):
            raise TypeError("not a JSON object")
    except (KeyError, TypeError, ValueError) as e:
        raise error(f"{path}: {what} metadata unreadable ({e})") from e
    return meta, blob["state_dict"]
