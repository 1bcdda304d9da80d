"""Closed-loop trackers: correct the simulated liquid with what the cameras see (SPEC §4).

Implemented: :class:`OpenLoop` (no correction), :class:`MapFilter` (thesis §7.2.2),
:class:`WarpField` (§7.2.3) and :class:`SPNetsPerception` (§8.4.2: SOLVEPERCEPTION with a
learned blending net, :mod:`.perception`, run as a term inside the PBF solver).
"""

from .base import Correction, Observation, OpenLoop, Tracker
from .perception import (BlendNet, PerceptionWeightsError, apply_field, blended_field, distance_field, load_blend_net,
                         model_labels, nearest_vectors, solve_perception)
from .spnets import PerceptionTerm, SPNetsPerception
from .map_filter import MapFilter, hypothesis_offsets, psi_image, se_kernel
from .warp import (CUTOFF_PX, DEFAULT_GAIN, LENGTH_PX, WarpField, image_scale, kernel_mass, lift, sample_bilinear,
                   sph_smooth, warp_image, warp_kernel)

__all__ = [
    "Correction", "Observation", "OpenLoop", "Tracker", "MapFilter", "hypothesis_offsets", "psi_image", "se_kernel",
    "BlendNet", "PerceptionWeightsError", "apply_field", "blended_field", "distance_field", "load_blend_net",
    "model_labels", "nearest_vectors", "solve_perception", "PerceptionTerm", "SPNetsPerception",
    "CUTOFF_PX", "DEFAULT_GAIN", "LENGTH_PX", "WarpField",
    "image_scale", "kernel_mass", "lift", "sample_bilinear", "sph_smooth", "warp_image", "warp_kernel",
]
