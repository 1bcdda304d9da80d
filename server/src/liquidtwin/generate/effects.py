"""Hidden effects: what the generated "world" may carry that liquidtwin's model does not.

Each effect is a physical term, a geometry change, a wrong initial condition or an
observation fault, with one main magnitude (``value``, in ``unit``) drawn from a realistic
range and at most one or two secondary parameters (``extra``) drawn from the seed. The
canonical names are the discrepancy report's candidate names (ARCHITECTURE.md).

The physics they are made of lives where the model can use it too: ``sim.terms``
(QuadraticDrag, UniformAcceleration, WallAdhesion), ``sim.sdf_ops`` (carve / solidify) and
the fluid parameters; the generator (``generate.world``) applies them to the world only.

>>> parse_effect("drag=2.5")             # Effect(name="drag", value=2.5, extra={})
>>> sample_effect("leak", rng)           # realistic random magnitude and position
>>> parse_effect_extra("blockage=1.0:leg=right")   # ("blockage", 1.0, {"leg": 1.0})
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class EffectKind:
    """Catalogue entry: ``ranges`` are the realistic (low, high) intervals of ``value``
    (several intervals when both directions are plausible, e.g. thinner or thicker)."""

    name: str
    kind: str                 # "physics" | "geometry" | "initial" | "observation"
    unit: str
    ranges: tuple[tuple[float, float], ...]
    doc: str

    def contains(self, value: float) -> bool:
        return any(lo <= value <= hi for lo, hi in self.ranges)


EFFECTS: dict[str, EffectKind] = {e.name: e for e in (
    EffectKind("drag", "physics", "1/m", ((1.0, 4.0),),
               "air drag on fast particles, a = -c |v| v (spray, breaking streams)"),
    EffectKind("wind", "physics", "m/s^2", ((0.5, 2.0),),
               "uniform horizontal acceleration (draught, fan); direction in extra['azimuth_deg']"),
    EffectKind("viscosity", "physics", "1/s", ((5.0, 25.0), (90.0, 115.0)),
               "the liquid's viscosity lambda_v differs from the model's (thinner or thicker)"),
    EffectKind("cohesion", "physics", "1", ((0.25, 0.45),),
               "stronger cohesion lambda_c than the model's (sticky, syrupy liquid)"),
    EffectKind("wall_adhesion", "physics", "1/s", ((15.0, 45.0),),
               "particles within about a particle spacing of a wall lose speed at this rate"),
    EffectKind("leak", "geometry", "m", ((0.004, 0.007),),
               "a round hole of this radius in the source container's wall; extra: its height as a "
               "fraction of the initial liquid depth and its azimuth"),
    EffectKind("blockage", "geometry", "1", ((0.4, 1.0),),
               "fraction of a spout's or pipe leg's cross-section obstructed; extra: which leg"),
    EffectKind("fill_error", "initial", "1", ((-0.35, -0.12), (0.12, 0.35)),
               "relative error of the stated initial fill (true = stated * (1 + value))"),
    EffectKind("time_offset", "observation", "s", ((-0.2, -0.05), (0.05, 0.2)),
               "images lag (value > 0) or lead the poses: an image stamped t shows time t - value"),
    EffectKind("camera_offset", "observation", "deg", ((0.7, 2.5),),
               "the stated camera extrinsics are off by this rotation (plus 5-15 mm of translation)"),
)}


@dataclass(frozen=True)
class Effect:
    """One hidden effect: canonical ``name``, magnitude ``value`` (unit of its kind) and
    secondary parameters ``extra`` (floats)."""

    name: str
    value: float
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.name not in EFFECTS:
            raise ValueError(f"unknown effect {self.name!r}; known: {', '.join(EFFECTS)}")
        if not math.isfinite(self.value):
            raise ValueError(f"effect {self.name}: value must be finite, got {self.value}")

    @property
    def kind(self) -> EffectKind:
        return EFFECTS[self.name]

    def as_dict(self) -> dict:
        return {"name": self.name, "value": self.value, "unit": self.kind.unit, "kind": self.kind.kind,
                "extra": dict(self.extra)}


def _draw(kind: EffectKind, rng: np.random.Generator) -> float:
    lo, hi = kind.ranges[int(rng.integers(len(kind.ranges)))]
    return float(round(rng.uniform(lo, hi), 6))


def _extras(name: str, rng: np.random.Generator) -> dict:
    if name == "wind":
        return {"azimuth_deg": float(round(rng.uniform(0.0, 360.0), 3))}
    if name == "leak":
        # Below the liquid's initial surface, on the pouring half of the wall (azimuth from +x
        # about +y; the lip is at 180°), where liquid presses on it before and while pouring.
        return {"height_fraction": float(round(rng.uniform(0.2, 0.6), 4)),
                "azimuth_deg": float(round(rng.uniform(120.0, 240.0), 3))}
    if name == "camera_offset":
        axis = rng.normal(size=3)
        shift = rng.normal(size=3)
        shift *= rng.uniform(0.005, 0.015) / np.linalg.norm(shift)
        return {"axis": [float(a) for a in axis / np.linalg.norm(axis)], "shift_m": [float(s) for s in shift]}
    if name == "blockage":
        return {"leg": float(rng.integers(2))}       # 0 = left / spout, 1 = right
    return {}


def sample_effect(name: str, rng: np.random.Generator, value: float | None = None,
                  extra: dict | None = None) -> Effect:
    """An effect with ``value`` (drawn from its realistic range if None) and drawn extras, of
    which those named in ``extra`` are replaced (the draws happen anyway, so the seed's other
    streams do not change)."""
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
    v = _draw(EFFECTS[name], rng) if value is None else float(value)
    drawn = _extras(name, rng)
    unknown = set(extra or {}) - set(drawn)
    if unknown:
        raise ValueError(f"effect {name}: unknown extra {sorted(unknown)}; it takes {sorted(drawn) or 'none'}")
    return Effect(name, v, drawn | dict(extra or {}))


def parse_effect(text: str) -> tuple[str, float | None]:
    """``"NAME=VALUE"`` or ``"NAME"`` (magnitude drawn from the seed) → (name, value)."""
    name, _, value = text.partition("=")
    name = name.strip()
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r} in {text!r}; known: {', '.join(EFFECTS)}")
    if not value.strip():
        return name, None
    try:
        v = float(value)
    except ValueError:
        raise ValueError(f"effect {name}: value {value!r} is not a number ({EFFECTS[name].unit})") from None
    if not math.isfinite(v):
        raise ValueError(f"effect {name}: value must be finite")
    return name, v


#: Named values an extra may take on the command line (``blockage=1.0:leg=left``).
_EXTRA_WORDS = {"leg": {"left": 0.0, "spout": 0.0, "right": 1.0}}


def parse_effect_extra(text: str) -> tuple[str, float | None, dict]:
    """``"NAME[=VALUE][:KEY=X[:KEY=X]]"`` → (name, value, extra): ``parse_effect`` plus fixed
    secondary parameters, numbers or, for ``leg``, ``left``/``right``."""
    head, *items = text.split(":")
    name, value = parse_effect(head)
    extra = {}
    for item in items:
        key, eq, raw = (part.strip() for part in item.partition("="))
        if not eq or not key or not raw:
            raise ValueError(f"effect {name}: extra {item!r} must read KEY=VALUE")
        words = _EXTRA_WORDS.get(key, {})
        try:
            extra[key] = words[raw] if raw in words else float(raw)
        except ValueError:
            known = f" or one of {', '.join(words)}" if words else ""
            raise ValueError(f"effect {name}: extra {key}={raw!r} is not a number{known}") from None
    return name, value, extra
