"""A session's files under ``--state-dir`` (docs/service.md "Nothing lost").

``<state-dir>/sessions/<s>/``: ``spec.pb`` (the serialized SessionSpec) and ``meta.json``
(id, client, creation, state) written at creation; ``checkpoint.pt`` = {"engine":
engine.state_dict(), "service": counters and stamps}, tensors and plain values only, written
to a temporary file, fsynced and renamed; ``log-NNNN.mcap`` segments (:mod:`.log`). A closed
session's meta.json says ``"state": "closed"`` and it is not restored.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch
from liquidtwin_proto import SessionSpec

SPEC = "spec.pb"
META = "meta.json"
CHECKPOINT = "checkpoint.pt"
CLOSED = "closed"


def sessions_root(state_dir) -> Path:
    """``<state-dir>/sessions``."""
    return Path(state_dir) / "sessions"


def _write_atomic(path: Path, write) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        write(f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    try:
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:
        pass


def write_session_files(directory, spec: SessionSpec, meta: dict) -> None:
    """spec.pb and meta.json of a new session (a stale checkpoint of an old one is removed)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    (d / CHECKPOINT).unlink(missing_ok=True)
    _write_atomic(d / SPEC, lambda f: f.write(spec.SerializeToString(deterministic=True)))
    write_meta(d, meta)


def write_meta(directory, meta: dict) -> None:
    """Replace meta.json atomically."""
    _write_atomic(Path(directory) / META, lambda f: f.write(json.dumps(meta, indent=1, sort_keys=True).encode()))


def read_meta(directory) -> dict:
    """meta.json of a session directory ({} when missing or unreadable)."""
    try:
        meta = json.loads((Path(directory) / META).read_text())
    except (OSError, ValueError):
        return {}
    return meta if isinstance(meta, dict) else {}


def read_spec(directory) -> SessionSpec:
    """The SessionSpec of a session directory (OSError / DecodeError when missing or bad)."""
    return SessionSpec.FromString((Path(directory) / SPEC).read_bytes())


def save_checkpoint(directory, engine_state: dict, service_state: dict) -> Path:
    """Write checkpoint.pt atomically; returns its path."""
    path = Path(directory) / CHECKPOINT
    _write_atomic(path, lambda f: torch.save({"engine": engine_state, "service": service_state}, f))
    return path


def load_checkpoint(directory) -> dict | None:
    """{"engine", "service"} of checkpoint.pt, or None when there is none yet."""
    path = Path(directory) / CHECKPOINT
    if not path.exists():
        return None
    state = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(state, dict) or not {"engine", "service"} <= state.keys():
        raise ValueError(f"{path} is not a liquidtwin session checkpoint")
    return state


def mark_closed(directory) -> None:
    """Record in meta.json that the session was closed (it is not restored)."""
    meta = read_meta(directory)
    meta["state"] = CLOSED
    write_meta(directory, meta)


def restorable(state_dir) -> list[tuple[str, Path]]:
    """(session id, directory) of every session under ``state_dir`` not marked closed."""
    root = sessions_root(state_dir)
    if not root.is_dir():
        return []
    out = []
    for d in sorted(root.iterdir()):
        if d.is_dir() and (d / SPEC).exists() and read_meta(d).get("state") != CLOSED:
            out.append((d.name, d))
    return out
