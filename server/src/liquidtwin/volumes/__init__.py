"""Model-based liquid volume estimation (SPEC §5, thesis 5.1.3): expected masks per candidate
volume (:mod:`.expected`), a histogram filter (HMM) over the volumes of a target container
(:mod:`.hmm`), and the two run over a recording (:mod:`.estimator`)."""

from .estimator import estimate_series
from .expected import (ExpectedMasks, LevelTable, container_hits, crossings, downsample_mask, expected_masks,
                       pixel_rays, quat_matrix)
from .transition import U_BINS, load_transition, scaled_transition
from .hmm import (P_LIQUID_IF_DRY, P_LIQUID_IF_LIQUID, VolumeFilter, default_transition,
                  learn_transition, log_likelihood)

__all__ = ["ExpectedMasks", "LevelTable", "P_LIQUID_IF_DRY", "P_LIQUID_IF_LIQUID", "VolumeFilter",
           "container_hits", "crossings", "default_transition", "downsample_mask", "estimate_series",
           "expected_masks", "learn_transition", "log_likelihood", "pixel_rays", "quat_matrix", "U_BINS", "load_transition",
           "scaled_transition"]
