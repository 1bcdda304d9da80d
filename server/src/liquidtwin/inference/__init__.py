"""Hidden-state inference (SPEC §3, thesis §7.4): banks of scene hypotheses simulated together,
scored against the observed liquid masks with the δ-likelihood (with a slack: ``likelihood``).

``infer_fill`` — the initial fill of a container (empty, 30, 60, 90 % by default);
``infer_blockage`` — the pipe junction's blockage (none, left/right × partial/full).
Both return a :class:`Posterior` (probabilities, log likelihoods, probability over time).
"""

from .bank import OFFSET_M, Bank, Hypothesis, make_tracker
from .blockage import BLOCKAGES, PARTIAL, blockage_hypotheses, infer_blockage
from .fill import FRACTIONS, fill_hypotheses, fill_name, infer_fill
from .likelihood import (DELTA, SLACK_PX, Posterior, disagreement, frame_log_likelihood, mask_log_likelihood, near,
                         normalise, slack_radius)
from .run import camera_at, run_bank, score

__all__ = [
    "OFFSET_M", "Bank", "Hypothesis", "make_tracker", "BLOCKAGES", "PARTIAL", "blockage_hypotheses", "infer_blockage",
    "FRACTIONS", "fill_hypotheses", "fill_name", "infer_fill", "DELTA", "SLACK_PX", "Posterior", "disagreement",
    "frame_log_likelihood", "mask_log_likelihood", "near", "normalise", "slack_radius", "camera_at", "run_bank",
    "score",
]
