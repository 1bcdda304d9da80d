"""Synthetic recordings with hidden effects: scenes, the world's physics, sensors, MCAP + truth."""

from .catalog import SCENES, Setup, build_setup
from .effects import EFFECTS, Effect, EffectKind, parse_effect, parse_effect_extra, sample_effect
from .generator import Generated, generate, listing

__all__ = ["SCENES", "Setup", "build_setup", "EFFECTS", "Effect", "EffectKind", "parse_effect", "parse_effect_extra", "sample_effect",
           "Generated", "generate", "listing"]
