"""Model-based liquid volume estimation (SPEC §5, thesis 5.1.3): expected masks per candidate
volume (:mod:`.expected`), a histogram filter (HMM) over the volumes of a target container
(:mod:`.hmm`), its learned transition (:mod:`.transition`, learned by :mod:`.learn`), and the
two run over a recording (:mod:`.estimator`)."""

from .estimator import estimate_series
from ._rays import crossings, pixel_rays, quat_matrix
from .expected import (MIN_DEPTH_SPACINGS, SURFACE_OFFSET_SPACINGS, ExpectedMasks, LevelTable, container_hits, downsample_mask,
                       expected_masks)
from .hmm import (P_LIQUID_IF_DRY, P_LIQUID_IF_LIQUID, VolumeFilter, default_transition,
                  learn_transition, log_likelihood)
from .transition import U_BINS, load_transition, scaled_transition

__all__ = ["MIN_DEPTH_SPACINGS", "SURFACE_OFFSET_SPACINGS", "ExpectedMasks", "LevelTable", "P_LIQUID_IF_DRY", "P_LIQUID_IF_LIQUID",
           "U_BINS", "VolumeFilter", "container_hits", "crossings", "default_transition", "downsample_mask",
           "estimate_series", "expected_masks", "learn_transition", "load_transition", "log_likelihood",
           "pixel_rays", "quat_matrix", "scaled_transition"]
