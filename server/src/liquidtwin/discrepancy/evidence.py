"""The structure of the base model's residuals: the signatures that point at a cause.

Each statistic is computed from the coarse masks and the recorded poses only, and reported
under the candidates it speaks for (report.json ``candidates[i].evidence``):

- ``shift_at_rest_cells``: mean (row, column) offset of the observed liquid from the model's in
  frames where the source is not turning — a camera offset shows even when nothing moves;
- ``shift_speed_corr``: correlation of the size of that offset with the source's angular
  speed — a time offset follows the motion;
- ``mass_ratio_early`` / ``mass_ratio_late``: observed / model liquid cells in the first and
  last third of the frames with liquid — a wrong fill shows from the start, a leak grows;
- ``extra_upright_cells``: observed liquid cells the model lacks while the source is upright
  (tilt < 30°) — a leak drips before any pouring;
- ``mean_shift_cells``: mean offset over all frames with liquid — drag shortens the stream,
  wind pushes it one way; viscosity, cohesion and adhesion change its width and timing.
"""

from __future__ import annotations

import math

import numpy as np

from .residuals import MIN_CELLS, centroids

UPRIGHT_RAD = math.radians(30.0)
REST_RAD_S = 0.3


def tilt_and_speed(ep, index: int) -> tuple[np.ndarray, np.ndarray]:
    q = ep.poses_at(ep.frame_t)[:, index, 3:]
    x, z = q[:, 0], q[:, 2]
    tilt = np.arccos(np.clip(1.0 - 2.0 * (x * x + z * z), -1.0, 1.0))
    speed = np.abs(np.gradient(tilt, ep.frame_t)) if len(tilt) > 1 else np.zeros_like(tilt)
    return tilt, speed


def _mean(a) -> float | None:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else None


def evidence(eps, sims, frames: list, model_cells: list, obs_cells: list) -> dict:
    """{candidate: {statistic: value}} from the base model's residuals (module doc); cells are
    (F, h, w) bool at each episode's mask ``frames`` (index arrays)."""
    shift, rest, corr_x, corr_y, early, late, extra = [], [], [], [], [], [], []
    for ep, sim, f, cm, co in zip(eps, sims, frames, model_cells, obs_cells):
        tilt, speed = (a[f] for a in tilt_and_speed(ep, sim.source_index))
        nm, no = cm.sum((1, 2)), co.sum((1, 2))
        both = (nm >= MIN_CELLS) & (no >= MIN_CELLS)
        d = centroids(co) - centroids(cm)
        shift.append(d[both])
        rest.append(d[both & (speed < REST_RAD_S)])
        corr_x.append(np.linalg.norm(d[both], axis=1))
        corr_y.append(speed[both])
        wet = np.nonzero((nm >= MIN_CELLS) | (no >= MIN_CELLS))[0]
        if wet.size >= 3:
            third = max(1, wet.size // 3)
            early.append(no[wet[:third]].sum() / max(nm[wet[:third]].sum(), 1))
            late.append(no[wet[-third:]].sum() / max(nm[wet[-third:]].sum(), 1))
        up = tilt < UPRIGHT_RAD
        extra.append(float((co[up] & ~cm[up]).sum(axis=(1, 2)).mean()) if up.any() else 0.0)
    sh = np.concatenate(shift) if shift else np.zeros((0, 2))
    rs = np.concatenate(rest) if rest else np.zeros((0, 2))
    cx, cy = np.concatenate(corr_x), np.concatenate(corr_y)
    corr = float(np.corrcoef(cx, cy)[0, 1]) if cx.size > 2 and cx.std() > 0 and cy.std() > 0 else None
    mean_shift = [float(v) for v in sh.mean(0)] if len(sh) else None
    rest_shift = [float(v) for v in rs.mean(0)] if len(rs) else None
    flow = {"mean_shift_cells": mean_shift, "mass_ratio_late": _mean(late)}
    return {
        "drag": flow, "wind": flow, "viscosity": flow, "cohesion": flow, "wall_adhesion": flow,
        "leak": {"extra_upright_cells": _mean(extra), "mass_ratio_early": _mean(early), "mass_ratio_late": _mean(late)},
        "blockage": {"mass_ratio_late": _mean(late)},
        "fill_error": {"mass_ratio_early": _mean(early), "mass_ratio_late": _mean(late)},
        "time_offset": {"shift_speed_corr": corr},
        "camera_offset": {"shift_at_rest_cells": rest_shift},
    }
