"""A model extension: the base model's calibrated parameters plus one candidate term.

An :class:`Extension` is what discrepancy discovery hands back and what a session can load
(``save_model`` / ``load_model``: a small JSON file, never pickle). It names the candidate and
its fitted parameters; :func:`apply` turns it into the pieces a rollout needs — the
FluidModel (parameters, extra terms, edited geometry), the initial fill scale, and the
observation changes (time offset, camera rotation).

Parameters per candidate (units):

==============  =====================================================================
drag            c 1/m: a = −c |v| v (``sim.QuadraticDrag``)
wind            ax, az m/s²: uniform horizontal acceleration (``sim.UniformAcceleration``)
viscosity       lambda_v 1/s: the XSPH viscosity coefficient
cohesion        lambda_c: the cohesion coefficient
wall_adhesion   k 1/s: speed lost near walls (``sim.WallAdhesion``, range one spacing)
leak            radius m, height_fraction, azimuth_deg: a hole in the source's wall
blockage        fraction: of the source's opening covered on the pouring side
fill_error      value: true fill = stated × (1 + value)
time_offset     s: an image stamped t shows time t − s
camera_offset   rx, ry, rz deg: rotation of the camera about its own axes
learned         w00 … w23: a = W [v, 1], the minimum-norm correction (``discrepancy.corrections``)
==============  =====================================================================
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ..camera.pinhole import matrix_to_quat
from ..sim import (LinearAcceleration, QuadraticDrag, UniformAcceleration, WallAdhesion, carve, quat_from_axis_angle, quat_to_matrix,
                   solidify)

MODEL_FILE_VERSION = 1
#: Canonical candidate names (ARCHITECTURE.md, Discrepancy report), in a fixed order.
CANDIDATES = ("drag", "wind", "viscosity", "cohesion", "wall_adhesion", "leak", "blockage", "fill_error",
              "time_offset", "camera_offset")
OBSERVATION = ("time_offset", "camera_offset")
#: Draws of each prediction (``Extension.draw`` 1 … K) the analysis measures the best candidates'
#: held-out gains from (``analysis.Options.ensemble``; 0: one rollout each).
ENSEMBLE = 4


@dataclass(frozen=True)
class Extension:
    """``name``: a candidate, ``"none"`` (the calibrated base) or ``"learned"``; ``params``:
    the candidate's fitted parameters (floats); ``base``: calibrated fluid parameters
    (``lambda_v``, ``lambda_c``) replacing the model's defaults; ``draw``: which realisation of
    the extension's prediction a rollout is (0: from the settled fill as it is; k ≥ 1: its
    initial velocities jittered by draw k, ``rollout.DRAW_JITTER``), for the ensemble gains
    (``analysis.Options.ensemble``). Not part of the model: model files do not hold it."""

    name: str = "none"
    params: dict = field(default_factory=dict)
    base: dict = field(default_factory=dict)
    draw: int = 0

    def __post_init__(self):
        if self.name not in CANDIDATES + ("none", "learned"):
            raise ValueError(f"unknown model extension {self.name!r}; known: {', '.join(CANDIDATES)}, none")
        for k, v in list(self.params.items()) + list(self.base.items()):
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"extension {self.name}: parameter {k} must be a finite number, got {v!r}")
        if isinstance(self.draw, bool) or not isinstance(self.draw, int) or self.draw < 0:
            raise ValueError(f"extension {self.name}: draw must be a whole number >= 0, got {self.draw!r}")

    def with_params(self, **params) -> "Extension":
        return Extension(self.name, {**self.params, **{k: float(v) for k, v in params.items()}}, self.base, self.draw)

    def drawn(self, draw: int) -> "Extension":
        """The same extension, realisation ``draw`` of its prediction."""
        return dataclasses.replace(self, draw=int(draw))

    def as_dict(self) -> dict:
        return {"version": MODEL_FILE_VERSION, "name": self.name, "params": dict(self.params), "base": dict(self.base)}

    @property
    def time_offset_s(self) -> float:
        return float(self.params.get("s", 0.0)) if self.name == "time_offset" else 0.0

    @property
    def fill_scale(self) -> float:
        return 1.0 + float(self.params.get("value", 0.0)) if self.name == "fill_error" else 1.0


def save_model(ext: Extension, path) -> Path:
    """Write ``ext`` as a model file (JSON)."""
    path = Path(path)
    path.write_text(json.dumps(ext.as_dict(), indent=2) + "\n")
    return path


def model_from_dict(doc) -> Extension:
    """Validate a parsed model file; ValueError with the reason when it is not one."""
    if not isinstance(doc, dict):
        raise ValueError("a model file holds a JSON object")
    if doc.get("version") != MODEL_FILE_VERSION:
        raise ValueError(f"model file version {doc.get('version')!r} is not {MODEL_FILE_VERSION}")
    unknown = set(doc) - {"version", "name", "params", "base"}
    if unknown:
        raise ValueError(f"model file: unknown fields {sorted(unknown)}")
    params, base = doc.get("params", {}), doc.get("base", {})
    if not isinstance(params, dict) or not isinstance(base, dict):
        raise ValueError("model file: params and base must be objects")
    bad = set(base) - {"lambda_v", "lambda_c"}
    if bad:
        raise ValueError(f"model file: base may set lambda_v and lambda_c only, not {sorted(bad)}")
    return Extension(str(doc.get("name", "none")), dict(params), dict(base))


def load_model(path) -> Extension:
    """Read a model file written by :func:`save_model`."""
    try:
        doc = json.loads(Path(path).read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not a JSON model file ({exc})") from None
    return model_from_dict(doc)


def rotation_deg(rx: float, ry: float, rz: float) -> torch.Tensor:
    """(3, 3) float64 rotation for a rotation vector given in degrees."""
    r = torch.tensor([rx, ry, rz], dtype=torch.float64)
    angle = float(r.norm())
    if angle < 1e-12:
        return torch.eye(3, dtype=torch.float64)
    return quat_to_matrix(quat_from_axis_angle(r / angle, math.radians(angle)))


def apply_physics(ext: Extension, model, sites=None):
    """The FluidModel of ``ext`` built on ``model`` (the base scene's). ``sites``: (leak, blockage)
    site functions of the source container (``generate.catalog.source_sites``), needed by
    ``leak`` and ``blockage``."""
    m = model.with_params(**ext.base) if ext.base else model
    p, n = ext.params, ext.name
    if n == "drag":
        return m.replace(terms=m.terms + (QuadraticDrag(torch.tensor(p["c"])),))
    if n == "wind":
        return m.replace(terms=m.terms + (UniformAcceleration(torch.tensor([p["ax"], 0.0, p["az"]])),))
    if n == "viscosity":
        return m.with_params(lambda_v=p["lambda_v"])
    if n == "cohesion":
        return m.with_params(lambda_c=p["lambda_c"])
    if n == "learned":
        return m.replace(terms=m.terms + (LinearAcceleration(learned_matrix(p)),))
    if n == "wall_adhesion":
        return m.replace(terms=m.terms + (WallAdhesion(torch.tensor(p["k"]), float(m.spacing)),))
    if n in ("leak", "blockage"):
        if sites is None:
            raise ValueError(f"extension {n}: the scene has no source container to edit")
        leak, block = sites
        objects = list(m.objects)
        if n == "leak":
            index, cut = leak(p["radius"], {"height_fraction": p["height_fraction"], "azimuth_deg": p["azimuth_deg"]})
            objects[index] = carve(objects[index], cut)
        else:
            index, solid = block(p["fraction"], {"leg": 0.0})
            objects[index] = solidify(objects[index], solid)
        return m.replace(objects=tuple(objects))
    return m


def learned_params(W) -> dict:
    """Extension params of a (3, 4) learned correction matrix."""
    return {f"w{i}{j}": float(W[i][j]) for i in range(3) for j in range(4)}


def learned_matrix(params: dict) -> torch.Tensor:
    """(3, 4) float32 matrix from ``learned_params``; ValueError when entries are missing."""
    try:
        return torch.tensor([[params[f"w{i}{j}"] for j in range(4)] for i in range(3)], dtype=torch.float32)
    except KeyError as exc:
        raise ValueError(f"learned extension: parameter {exc.args[0]} missing (w00 … w23)") from None


def camera_for(ext: Extension, camera):
    """The camera of ``ext``: rotated about its own axes for ``camera_offset``."""
    if ext.name != "camera_offset":
        return camera
    pose = camera.pose.detach().double()
    R = quat_to_matrix(pose[3:] / pose[3:].norm())
    R2 = R @ rotation_deg(ext.params["rx"], ext.params["ry"], ext.params["rz"])
    return dataclasses.replace(camera, pose=torch.cat([pose[:3], matrix_to_quat(R2)]))
