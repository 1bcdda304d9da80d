"""``SessionSpec.pose_filter`` from the command-line form ``M,RAD[,ACC,ANGACC]``."""

from __future__ import annotations

import math

from .liquidtwin_pb2 import PoseFilter


def parse_pose_filter(text: str) -> PoseFilter:
    """``M,RAD[,ACC,ANGACC]``: the tracker's white noise per axis (m, rad) and optionally the
    process noise (m/s², rad/s²), finite numbers >= 0. ValueError otherwise."""
    try:
        vals = [float(v) for v in str(text).split(",")]
    except ValueError:
        vals = []
    if len(vals) not in (2, 4) or not all(math.isfinite(v) and v >= 0 for v in vals):
        raise ValueError(f"expected M,RAD[,ACC,ANGACC] (numbers >= 0), got {text!r}")
    vals += [0.0, 0.0]
    return PoseFilter(position_noise_m=vals[0], rotation_noise_rad=vals[1], acceleration_m_s2=vals[2],
                      angular_acceleration_rad_s2=vals[3])
