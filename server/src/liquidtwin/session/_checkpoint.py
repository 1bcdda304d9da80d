"""A session engine's checkpoint: what changes, as tensors, numbers and strings only."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import torch

from ..sim import FluidState
from ._task import create_task, task_from_str
from .errors import BAD_REQUEST, EngineError

VERSION = 1


def spec_digest(spec) -> str:
    """SHA-256 of the spec's deterministic serialisation (a checkpoint names its spec)."""
    return hashlib.sha256(spec.SerializeToString(deterministic=True)).hexdigest()


def engine_state(engine) -> dict:
    """Loadable with ``torch.load(..., weights_only=True)``."""
    s = engine._state
    out = {
        "version": VERSION, "spec_sha256": spec_digest(engine.spec),
        "x": s.x.detach().cpu().clone(), "v": s.v.detach().cpu().clone(), "ids": s.ids.cpu().clone(),
        "poses": s.poses.detach().cpu().clone(), "t": float(s.t),
        "sim_t": float(engine._sim_t), "has_frame": engine._frame_t is not None,
        "frame_t": float(engine._frame_t or 0.0), "frame_poses": torch.as_tensor(engine._frame_poses).clone(),
        "frames": int(engine._frames), "cameras": engine._cameras.state_dict(),
        "tracker": engine._tracker.state_dict(),
        # the task and its controller (the task's state_dict; "task" "" = none)
        **(engine._task.state_dict() if engine._task is not None else
           {"task": "", "task_base": 0.0, "control_frame": -1, "pid": {}}),
        # the loaded model extension (model file JSON; "" = none), its initial fill when it
        # differs from the spec's (fill_error), and the steps kept for its time offset
        "extension": json.dumps(engine._ext.as_dict()) if engine._ext.name != "none" or engine._ext.base else "",
        "history": engine._history.state_dict(),
    }
    if engine._pose_filter is not None:
        out["pose_filter"] = engine._pose_filter.state_dict()
    if engine._initial is not engine._scene.state:
        x0, v0 = engine._initial.by_id()
        out["initial_x"], out["initial_v"] = x0.detach().cpu().clone(), v0.detach().cpu().clone()
        out["initial_ml_per_particle"] = float(engine._ml_per_particle)
    return out


def load_engine_state(engine, state: dict) -> None:
    """Restore :func:`engine_state` into ``engine`` (built from the same spec)."""
    if not isinstance(state, dict) or state.get("version") != VERSION:
        raise EngineError(BAD_REQUEST, f"not a session engine checkpoint of version {VERSION}")
    if state["spec_sha256"] != spec_digest(engine.spec):
        raise EngineError(BAD_REQUEST, "the checkpoint was written by a session with another spec")
    _load_extension(engine, state)
    n = engine._initial.x.shape[0]
    x, ids = state["x"], state["ids"]
    if x.dim() != 2 or x.shape[1] != 3 or x.shape[0] > n or tuple(ids.shape) != (x.shape[0],) \
            or (x.shape[0] and (int(ids.min()) < 0 or int(ids.max()) >= n or ids.unique().numel() != ids.numel())):
        raise EngineError(BAD_REQUEST, f"checkpoint holds {tuple(x.shape)} particles with ids that are not "
                                       f"distinct labels of the scene's {n}")
    if engine._pose_filter is not None:
        engine._pose_filter.load_state_dict(state.get("pose_filter", {}))
    dev = engine._scene.state.x.device
    engine._state = FluidState(state["x"].to(dev), state["v"].to(dev), state["ids"].to(dev),
                               state["poses"].to(dev), float(state["t"]))
    engine._sim_t = float(state["sim_t"])
    engine._frame_t = float(state["frame_t"]) if state["has_frame"] else None
    engine._frame_poses = state["frame_poses"].numpy().astype(np.float64)
    engine._frames = int(state["frames"])
    engine._volumes = None
    engine._cameras.load_state_dict(state["cameras"])
    engine._tracker.load_state_dict(state["tracker"])
    engine._task = create_task(task_from_str(state["task"]), engine, state=state) if state["task"] else None
    engine._history.load_state_dict(state.get("history", []), dev)


def _load_extension(engine, state: dict) -> None:
    """Load the checkpoint's model extension (none in checkpoints written before extensions)."""
    from ..discrepancy.model import Extension, model_from_dict
    try:
        ext = model_from_dict(json.loads(state["extension"])) if state.get("extension") else Extension()
    except ValueError as exc:
        raise EngineError(BAD_REQUEST, f"the checkpoint's model extension is not valid: {exc}") from None
    initial = (state["initial_x"], state["initial_v"], state["initial_ml_per_particle"]) if "initial_x" in state else None
    engine.load_extension(engine.prepare_extension(ext, initial=initial))
