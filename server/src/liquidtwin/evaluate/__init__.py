"""Evaluations of tracking and hidden-state inference on generated benchmarks (issue 5).

``benchmark`` defines the shared pouring cases and caches their recordings; ``replay`` feeds
a recording to a session engine; one module per ``liquidtwin evaluate`` kind.
"""

from .benchmark import Case, cases, ensure, recording_path
from .replay import MODES, Replay, engine_for, replay

__all__ = ["Case", "cases", "ensure", "recording_path", "MODES", "Replay", "engine_for", "replay"]
