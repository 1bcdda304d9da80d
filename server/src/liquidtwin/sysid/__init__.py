"""System identification: fluid parameters fitted by gradients through SPNets (SPEC §7).

``simulate_sequence`` makes a ground-truth sequence (the thesis's ladle experiment),
``fit`` estimates λ parameters from it with the L1 (particle correspondence) or projection
(images, no correspondence) loss. ``liquidtwin fit`` is the command line.
"""

from .data import Sequence, SequenceError, load_sequence, save_sequence, simulate_sequence
from .fit import LOSSES, SCALES, FitConfig, FitResult, fit
from .losses import l1_loss, projection, projection_loss, seen

__all__ = ["FitConfig", "FitResult", "LOSSES", "SCALES", "Sequence", "SequenceError", "fit", "l1_loss",
           "load_sequence", "projection", "projection_loss", "save_sequence", "seen", "simulate_sequence"]
