"""Controllers that act on the session's liquid (SPEC §7): PD pour-to-volume from volume
estimates, and model-predictive control with gradients through SPNets (``MPC``; the plate
task in ``plate``)."""

from .mpc import MPC, ControlError, ControlSpace
from .pid import THESIS_START_ANGLE, PourPID, thesis_gains

__all__ = ["ControlError", "ControlSpace", "MPC", "PourPID", "THESIS_START_ANGLE", "thesis_gains"]
