"""The liquid detector of sessions whose masks come from RGB (``SessionSpec.mask_source``).

``"mask"`` (or empty): masks are streamed in, images are only logged. ``"rgb"``: the
server's detector (``ServeConfig.detector``, default the shipped model) turns every
``in/image`` frame into the mask the tracker and the overlay use.
"""

from __future__ import annotations

from ..session import EngineError
from ..session.errors import BAD_REQUEST, INFEASIBLE

MASK_SOURCES = ("", "mask", "rgb")


def check_mask_source(spec) -> None:
    """EngineError(BAD_REQUEST) for an unknown ``spec.mask_source``."""
    if spec.mask_source not in MASK_SOURCES:
        raise EngineError(BAD_REQUEST, f"mask_source must be 'mask' or 'rgb', got {spec.mask_source!r}")


def make_detector(spec, config):
    """A per-session StreamDetector for ``mask_source == "rgb"``, else None. EngineError
    (INFEASIBLE) when the server's model file cannot be used."""
    check_mask_source(spec)
    if spec.mask_source != "rgb":
        return None
    from ..perception import PerceptionModelError
    from ..perception.stream import StreamDetector
    try:
        return StreamDetector.from_file(getattr(config, "detector", None))
    except PerceptionModelError as e:
        raise EngineError(INFEASIBLE, f"mask_source 'rgb': this server's detector is unusable: {e}") from e
