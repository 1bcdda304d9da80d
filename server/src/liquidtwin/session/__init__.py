"""Session engine: one robot session's liquid twin (simulation, tracking, volumes, control).

No networking here: the Zenoh service (``liquidtwin.service``) owns one
:class:`SessionEngine` per session and feeds it frames; docs/service.md describes the wire.
"""

from .engine import CorrectionResult, FrameResult, SessionEngine
from .errors import EngineError
from .overlay import BACKGROUND_RGB, MODEL_RGB, OBSERVED_RGB, OVERLAP_RGB, Overlay, make_overlay, pack_rgb

__all__ = [
    "CorrectionResult", "EngineError", "FrameResult", "SessionEngine", "BACKGROUND_RGB", "MODEL_RGB",
    "OBSERVED_RGB", "OVERLAP_RGB", "Overlay", "make_overlay", "pack_rgb",
]
