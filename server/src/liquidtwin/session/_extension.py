"""A discrepancy model extension loaded into a session (``SessionEngine.load_extension``).

:func:`prepare` checks an :class:`~liquidtwin.discrepancy.Extension` against the session's
scene and builds what the engine then runs: the step model (``apply_physics``: calibrated
λ_v/λ_c, extra terms, edited source geometry), and for ``fill_error`` the source container
refilled with the stated amount × ``fill_scale`` the way the session's own fill is made
(``session/_build.py``: ``fill_container``, settled ``SETTLE_S``), other containers' fills
kept. The source container is the scene's first fill, as in the discrepancy analysis.

:class:`History` keeps the particle states of the last few steps so a ``time_offset``
extension can compare a mask stamped t with the model as it was at t − s.

``liquidtwin.discrepancy`` builds on this package (its rollouts use the session's scene
builder), so it is imported where it is used, never at module level.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..sim import FluidModel, FluidState, make_state
from .errors import BAD_REQUEST, INFEASIBLE, EngineError

#: Longest time offset a session honours, s (the particle history it keeps).
MAX_TIME_OFFSET_S = 0.5
#: Parameters each extension needs (exactly these), and checks of their values.
PARAMS = {
    "none": (), "drag": ("c",), "wind": ("ax", "az"), "viscosity": ("lambda_v",), "cohesion": ("lambda_c",),
    "wall_adhesion": ("k",), "leak": ("radius", "height_fraction", "azimuth_deg"), "blockage": ("fraction",),
    "fill_error": ("value",), "time_offset": ("s",), "camera_offset": ("rx", "ry", "rz"),
    "learned": tuple(f"w{i}{j}" for i in range(3) for j in range(4)),
}
_RANGES = {  # name: (lowest, highest, unit) — open below where the value must stay positive
    "c": (0.0, None, "1/m"), "lambda_v": (0.0, None, "1/s"), "lambda_c": (0.0, None, ""), "k": (0.0, None, "1/s"),
    "radius": (1e-4, 0.05, "m"), "height_fraction": (0.0, 1.0, ""), "fraction": (0.0, 1.0, ""),
    "value": (-0.95, 3.0, ""), "s": (-MAX_TIME_OFFSET_S, MAX_TIME_OFFSET_S, "s"),
}


@dataclass(frozen=True, eq=False)
class Prepared:
    """An extension (``ext``, a :class:`~liquidtwin.discrepancy.Extension`) ready to load:
    ``model`` the FluidModel the steps use (before the tracker's terms), ``initial`` the
    settled fill a reset goes back to (on the session's device), ``ml_per_particle`` its
    settled ml per particle (a refill packs its particles a little differently)."""

    ext: object
    model: FluidModel
    initial: FluidState
    ml_per_particle: float


def check(ext) -> None:
    """EngineError(BAD_REQUEST) when ``ext`` lacks a parameter, has an unknown one, or one out of range."""
    from ..discrepancy.model import Extension
    if not isinstance(ext, Extension):
        raise EngineError(BAD_REQUEST, f"a model extension must be a discrepancy.Extension, got {type(ext).__name__}")
    need = PARAMS[ext.name]
    missing, extra = [k for k in need if k not in ext.params], sorted(set(ext.params) - set(need))
    if missing or extra:
        raise EngineError(BAD_REQUEST, f"model extension {ext.name!r} takes parameters {list(need)}; "
                                       f"missing {missing}, unknown {extra}")
    for key, v in list(ext.params.items()) + list(ext.base.items()):
        lo, hi, unit = _RANGES.get(key, (None, None, ""))
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise EngineError(BAD_REQUEST, f"model extension {ext.name!r}: {key} = {v} {unit} is outside "
                                           f"[{lo}, {'∞' if hi is None else hi}]")


def source_of(scene, spec) -> tuple[str, int]:
    """(name, object index) of the source container: the scene's first fill."""
    name = spec.scene.fills[0].container
    return name, scene.names.index(name)


def _sites(scene, spec):
    from ..generate.catalog import source_sites
    name, k = source_of(scene, spec)
    try:
        return source_sites(k, scene.objects[k], scene.fills[name].settled_ml)
    except (AttributeError, ValueError):
        return None                      # not a round container: no leak / blockage site


def _cpu(model: FluidModel) -> FluidModel:
    return model.replace(objects=tuple(g.to(device="cpu") for g in model.objects),
                         params=model.params.to(device="cpu"))


def refill(scene, spec, scale: float, device: str) -> tuple[FluidState, float]:
    """The scene's initial fill with the source holding its asked ml × ``scale`` (settled as
    the session's own fill) and its settled ml per particle; EngineError(INFEASIBLE) when that
    does not fit."""
    from ..scenes.fill import fill_container
    from ._build import SETTLE_S
    name, k = source_of(scene, spec)
    rep = scene.fills[name]
    model = scene.model if device == "cpu" else _cpu(scene.model)
    poses = torch.as_tensor(scene.initial_poses)
    try:
        s, new = fill_container(model, poses, k, scene.objects[k], volume_ml=max(rep.asked_ml * round(scale, 4), 1e-3),
                                settle_s=SETTLE_S)
    except ValueError as exc:
        raise EngineError(INFEASIBLE, f"model extension fill_error: cannot refill {name!r} × {scale:.3f}: {exc}") from None
    xs, vs = s.by_id()
    x0, v0 = scene.state.by_id()
    others = int(x0.shape[0]) - rep.particles          # the other fills follow the source's, in id order
    if others:
        xs, vs = torch.cat([xs, x0[-others:].cpu()]), torch.cat([vs, v0[-others:].cpu()])
    ml = new.settled_ml + sum(r.settled_ml for n, r in scene.fills.items() if n != name)
    return make_state(xs, vs, poses=poses, dtype=torch.float32, device=device), ml / int(xs.shape[0])


def prepare(ext, scene, spec, device: str, initial: tuple | None = None) -> Prepared:
    """Check ``ext`` and build its model and initial fill (slow for ``fill_error``: a refill).
    ``initial``: (x (N, 3) m, v (N, 3) m/s, ml per particle) of an already made fill (a
    checkpoint's)."""
    from ..discrepancy.model import apply_physics
    check(ext)
    try:
        model = apply_physics(ext, scene.model, _sites(scene, spec) if ext.name in ("leak", "blockage") else None)
    except ValueError as exc:
        raise EngineError(BAD_REQUEST, f"model extension {ext.name!r}: {exc}") from None
    if initial is not None:
        x, v, ml = initial
        state = make_state(x, v, poses=torch.as_tensor(scene.initial_poses), dtype=torch.float32, device=device)
    elif ext.fill_scale != 1.0:
        state, ml = refill(scene, spec, ext.fill_scale, device)
    else:
        state, ml = scene.state, scene.ml_per_particle
    return Prepared(ext, model, state, float(ml))


class History:
    """(time s, FluidState) of the latest steps, spanning at most ``span_s`` (+ one step)."""

    def __init__(self):
        self.span_s = 0.0
        self.items: list[tuple[float, FluidState]] = []

    def push(self, t: float, state: FluidState) -> None:
        if self.span_s <= 0:
            return
        self.items.append((float(t), state))
        while len(self.items) > 1 and self.items[1][0] <= t - self.span_s:
            self.items.pop(0)

    def at(self, t: float) -> FluidState | None:
        """The kept state nearest to time ``t`` (s); None when none is kept."""
        if not self.items:
            return None
        return min(self.items, key=lambda it: (abs(it[0] - t), -it[0]))[1]

    def clear(self) -> None:
        self.items = []

    def state_dict(self) -> list:
        return [{"t": t, "x": s.x.detach().cpu().clone(), "v": s.v.detach().cpu().clone(), "ids": s.ids.cpu().clone(),
                 "poses": s.poses.detach().cpu().clone(), "st": float(s.t)} for t, s in self.items]

    def load_state_dict(self, items: list, device) -> None:
        self.items = [(float(d["t"]), FluidState(d["x"].to(device), d["v"].to(device), d["ids"].to(device),
                                                 d["poses"].to(device), float(d["st"]))) for d in items]
