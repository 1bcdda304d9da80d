"""Closed-loop trackers: correct the simulated liquid with what the cameras see (SPEC §4).

Implemented: :class:`OpenLoop` (no correction), :class:`MapFilter` (thesis §7.2.2) and
:class:`WarpField` (§7.2.3). SPNets + perception (§8.4.2) plugs in later as a further
:class:`Tracker` subclass.
"""

from .base import Correction, Observation, OpenLoop, Tracker
from .map_filter import MapFilter, hypothesis_offsets, psi_image, se_kernel
from .warp import (CUTOFF_PX, DEFAULT_GAIN, LENGTH_PX, WarpField, image_scale, kernel_mass, lift, sample_bilinear,
                   sph_smooth, warp_image, warp_kernel)

__all__ = [
    "Correction", "Observation", "OpenLoop", "Tracker", "MapFilter", "hypothesis_offsets", "psi_image", "se_kernel",
    "CUTOFF_PX", "DEFAULT_GAIN", "LENGTH_PX", "WarpField",
    "image_scale", "kernel_mass", "lift", "sample_bilinear", "sph_smooth", "warp_image", "warp_kernel",
]
