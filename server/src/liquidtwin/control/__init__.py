"""Controllers that act on the session's liquid estimates (SPEC §7): PD pour-to-volume."""

from .pid import THESIS_START_ANGLE, PourPID, thesis_gains

__all__ = ["PourPID", "THESIS_START_ANGLE", "thesis_gains"]
