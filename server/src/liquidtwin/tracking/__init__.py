"""Closed-loop trackers: correct the simulated liquid with what the cameras see (SPEC §4).

Implemented: :class:`OpenLoop` (no correction) and :class:`WarpField` (thesis §7.2.3). The
MAP filter (§7.2.2) and SPNets + perception (§8.4.2) plug in later as further
:class:`Tracker` subclasses.
"""

from .base import Correction, Observation, OpenLoop, Tracker
from .warp import (CUTOFF_PX, DEFAULT_GAIN, LENGTH_PX, WarpField, image_scale, kernel_mass, lift, sample_bilinear,
                   sph_smooth, warp_image, warp_kernel)

__all__ = [
    "Correction", "Observation", "OpenLoop", "Tracker", "CUTOFF_PX", "DEFAULT_GAIN", "LENGTH_PX", "WarpField",
    "image_scale", "kernel_mass", "lift", "sample_bilinear", "sph_smooth", "warp_image", "warp_kernel",
]
