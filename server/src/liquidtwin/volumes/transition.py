"""The volume filter's shipped transition (learned by ``python -m liquidtwin.volumes.learn``)
and its scaling to a session's bins in ml."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .hmm import default_transition

#: Volume bins as fractions of the scene's liquid: 0 … 1.2 in 61 bins (0.02 apart).
U_BINS = np.linspace(0.0, 1.2, 61)
#: The shipped transition (learned by this module's command).
SHIPPED = Path(__file__).resolve().parents[1] / "data" / "volume_transition.npz"
#: Every transition keeps at least this probability (the filter must recover from a wrong belief).
FLOOR = 1e-6


def load_transition(path: Path | str = SHIPPED) -> tuple[np.ndarray, np.ndarray]:
    """(u_bins (K,) fractions of the scene's liquid, transition (K, K)) from a learned ``.npz``."""
    with np.load(path, allow_pickle=False) as z:
        u, T = np.asarray(z["u_bins"], float), np.asarray(z["transition"], float)
    if u.ndim != 1 or T.shape != (len(u), len(u)) or not np.allclose(T.sum(1), 1.0, atol=1e-6):
        raise ValueError(f"{path}: not a volume transition file (u_bins (K,), transition (K, K) rows summing to 1)")
    return u, T


def scaled_transition(total_ml: float, capacity_ml: float, path: Path | str = SHIPPED
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(bins (K',) ml, transition (K', K')) for a container of ``capacity_ml`` in a scene
    holding ``total_ml`` of liquid: the learned fractional bins × total, cut at the capacity
    (rows renormalised), with :data:`FLOOR` on every entry."""
    if not (np.isfinite(total_ml) and total_ml > 0 and np.isfinite(capacity_ml) and capacity_ml > 0):
        raise ValueError(f"total liquid and capacity must be > 0 ml, got {total_ml}, {capacity_ml}")
    u, T = load_transition(path)
    bins = u * total_ml
    keep = int(np.searchsorted(bins, capacity_ml * (1 + 1e-9), side="right"))
    if keep < 5:                          # a container far smaller than the liquid: default band
        bins = np.linspace(0.0, capacity_ml, 21)
        return bins, default_transition(len(bins), FLOOR)
    bins, T = bins[:keep], T[:keep, :keep] + FLOOR
    return bins, T / T.sum(1, keepdims=True)


