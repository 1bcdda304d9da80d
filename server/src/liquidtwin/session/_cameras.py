"""The cameras a session knows: intrinsics and pose arrive separately (spec, streams)."""

from __future__ import annotations

import numpy as np
import torch
from liquidtwin_proto import liquidtwin_pb2 as pb

from ..camera import Camera
from ..recordings.base import check_camera_name
from .errors import BAD_REQUEST, UNKNOWN_NAME, EngineError

QUAT_TOL = 1e-3     # |‖q‖ − 1| accepted in poses (trackers round their output)


def check_pose(pose, what: str) -> np.ndarray:
    """A (7,) pose (tx ty tz m, qx qy qz qw) as float64 with its quaternion normalised."""
    p = np.asarray(pose, dtype=np.float64).reshape(-1)
    if p.shape != (7,) or not np.isfinite(p).all():
        raise EngineError(BAD_REQUEST, f"{what}: pose must be 7 finite numbers (tx ty tz qx qy qz qw), got {p.tolist()}")
    n = float(np.linalg.norm(p[3:]))
    if abs(n - 1.0) > QUAT_TOL:
        raise EngineError(BAD_REQUEST, f"{what}: pose quaternion must have unit length (±{QUAT_TOL}), its norm is {n:.6g}")
    return np.concatenate([p[:3], p[3:] / n])


class Cameras:
    """name → {"K": (3, 3), "D": (5,), "width", "height", "pose": (7,)} (any subset)."""

    def __init__(self, spec: pb.SessionSpec):
        self.known: dict[str, dict] = {name: {} for name in spec.scene.cameras}
        for c in spec.cameras:
            self.set(c.name, K=list(c.k) or None, D=list(c.d) or None, width=c.width or None,
                     height=c.height or None, pose=list(c.pose) or None)

    def set(self, name, *, K=None, D=None, width=None, height=None, pose=None) -> None:
        try:
            check_camera_name(name)
        except ValueError as exc:
            raise EngineError(BAD_REQUEST, str(exc)) from None
        entry = dict(self.known.get(name, {}))
        for k, v in (("width", width), ("height", height)):
            if v is not None:
                if isinstance(v, bool) or int(v) != v or int(v) <= 0:
                    raise EngineError(BAD_REQUEST, f"camera {name!r}: {k} must be a positive whole number of px, got {v!r}")
                entry[k] = int(v)
        if D is not None:
            d = np.asarray(D, dtype=np.float64).reshape(-1)
            if d.size not in (0, 4, 5) or not np.isfinite(d).all():
                raise EngineError(BAD_REQUEST, f"camera {name!r}: D must be 5 finite plumb_bob numbers, got {d.tolist()}")
            entry["D"] = np.concatenate([d, np.zeros(5 - d.size)])
        if K is not None:
            k = np.asarray(K, dtype=np.float64).reshape(-1)
            if k.size != 9:
                raise EngineError(BAD_REQUEST, f"camera {name!r}: K must be 3×3 (9 numbers), got {k.size}")
            entry["K"] = k.reshape(3, 3)
        if pose is not None:
            entry["pose"] = check_pose(pose, f"camera {name!r}")
        if {"K", "width", "height"} <= entry.keys():
            self._build(name, entry)     # validates the calibration as a whole
        self.known[name] = entry

    def _build(self, name: str, e: dict) -> Camera:
        pose = e.get("pose", np.array([0, 0, 0, 0, 0, 0, 1.0]))
        try:
            return Camera.from_calibration(np.array(e["K"]), np.array(e.get("D", np.zeros(5))), e["width"], e["height"],
                                           torch.tensor(pose), name=name)
        except ValueError as exc:
            raise EngineError(BAD_REQUEST, f"camera {name!r}: {exc}") from None

    def size(self, name: str) -> tuple[int, int] | None:
        e = self.known.get(name, {})
        return (e["height"], e["width"]) if "height" in e and "width" in e else None

    def camera(self, name: str) -> Camera:
        """The usable camera ``name`` (intrinsics, size and pose known)."""
        if name not in self.known:
            raise EngineError(UNKNOWN_NAME, f"no camera {name!r}; known cameras: {sorted(self.known)}")
        e = self.known[name]
        missing = [k for k in ("K", "width", "height", "pose") if k not in e]
        if missing:
            raise EngineError(BAD_REQUEST, f"camera {name!r} is not usable yet: no {', '.join(missing)} "
                                           f"(send its calibration and its pose first)")
        return self._build(name, e)

    def state_dict(self) -> dict:
        return {name: {k: (torch.tensor(v) if isinstance(v, np.ndarray) else v) for k, v in e.items()}
                for name, e in self.known.items()}

    def load_state_dict(self, state: dict) -> None:
        self.known = {name: {k: (v.numpy() if isinstance(v, torch.Tensor) else v) for k, v in e.items()}
                      for name, e in state.items()}
