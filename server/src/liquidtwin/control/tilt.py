"""Tilting a held container to pour: about a horizontal world axis through the point of its
rim nearest the target, so the opening turns towards the target and the stream leaves from
that point (the thesis's cup turns about its lip, §8.3.3).

A service session fixes the geometry when a pour task is set (:func:`pour_axis`): the axis
``a = up × d`` (world up +y, d the horizontal direction from source to target; a positive
turn about a takes the container's +y towards d) and the pivot, the rim vertex furthest
along d, kept in the object frame so it follows the container as the robot moves it. The
robot is told both with every control (``Control.axis_point_m``, ``axis_direction``);
:func:`tilt_space` is the MPC's model of that motion from the current pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..scenes.motions import quat_axis_angle, quat_matrix, quat_multiply
from .mpc import ControlSpace

UP = np.array([0.0, 1.0, 0.0])
#: Vertices this close below the rim's top count as rim, m.
RIM_BAND_M = 0.003


def tilt_from_upright(pose: np.ndarray) -> float:
    """Angle (rad) between an object's +y axis and the world's +y, from its (7,) pose."""
    x, y, z, w = pose[3:]
    r11 = 1.0 - 2.0 * (x * x + z * z)
    return math.acos(min(1.0, max(-1.0, r11)))


@dataclass(frozen=True)
class PourAxis:
    """pivot_local: (3,) m, the pivot in the source's frame; axis: (3,) unit, world."""

    pivot_local: np.ndarray
    axis: np.ndarray

    def pivot_world(self, pose: np.ndarray) -> np.ndarray:
        """(3,) m: the pivot where the source at ``pose`` (7,) has it."""
        pose = np.asarray(pose, float)
        return quat_matrix(pose[3:]) @ self.pivot_local + pose[:3]


def pour_axis(vertices: np.ndarray, source_pose: np.ndarray, target_position: np.ndarray) -> PourAxis:
    """The pour geometry (module doc) of a source with mesh ``vertices`` (V, 3) m (object
    frame, +y its up) at ``source_pose`` (7,), pouring towards ``target_position`` (3,) m.
    A target straight below (< 1 mm off horizontally) gets d = +x."""
    pose = np.asarray(source_pose, float)
    d = np.asarray(target_position, float) - pose[:3]
    d[1] = 0.0
    n = float(np.linalg.norm(d))
    d = d / n if n > 1e-3 else np.array([1.0, 0.0, 0.0])
    axis = np.cross(UP, d)
    v = np.asarray(vertices, float)
    rim = v[v[:, 1] >= v[:, 1].max() - RIM_BAND_M]
    world = rim @ quat_matrix(pose[3:]).T + pose[:3]
    return PourAxis(rim[int(np.argmax(world @ d))].copy(), axis / np.linalg.norm(axis))


def turn_pose(pose: np.ndarray, point, axis, angle: float) -> np.ndarray:
    """(7,) pose turned by ``angle`` rad about world ``axis`` (3,) through ``point`` (3,) m:
    what a robot does with a Control's rate over a frame (``angle`` = rate × frame time)."""
    pose, point = np.asarray(pose, float), np.asarray(point, float)
    q = quat_axis_angle(axis, angle)
    return np.concatenate([point + quat_matrix(q) @ (pose[:3] - point), quat_multiply(q, pose[3:])])


def quat_mul_t(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a ⊗ b of (..., 4) (x, y, z, w) quaternions (rotation b, then a)."""
    ax, ay, az, aw = a.unbind(-1)
    bx, by, bz, bw = b.unbind(-1)
    return torch.stack([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz], -1)


def tilt_space(base_poses, index: int, pivot: np.ndarray, axis: np.ndarray, tilt_now: float,
               max_angle: float, max_rate: float) -> ControlSpace:
    """ControlSpace of object ``index``'s tilt (rad from upright, one dimension) when it turns
    from its pose in ``base_poses`` (M, 7), now at ``tilt_now``, about ``axis`` (3,) through
    ``pivot`` (3,) m: tilt q puts it at the pose turned by q − tilt_now. Limits: 0 … max_angle,
    rate ± max_rate."""
    base = torch.as_tensor(np.asarray(base_poses, float), dtype=torch.float64)
    p0, q0 = base[index, :3], base[index, 3:] / base[index, 3:].norm()
    c = torch.as_tensor(np.asarray(pivot, float), dtype=torch.float64)
    a = torch.as_tensor(np.asarray(axis, float), dtype=torch.float64)
    r = p0 - c

    def to_pose(q):
        turn = q[:, 0] - tilt_now
        cos, sin = torch.cos(turn)[:, None], torch.sin(turn)[:, None]
        pos = c + r * cos + torch.linalg.cross(a, r) * sin + a * (a @ r) * (1.0 - cos)    # Rodrigues
        half = 0.5 * turn[:, None]
        qa = torch.cat([a * torch.sin(half), torch.cos(half)], 1)
        return torch.cat([pos, quat_mul_t(qa, q0.expand_as(qa))], 1)

    t = lambda v: torch.tensor([v], dtype=torch.float64)  # noqa: E731
    if not (math.isfinite(max_angle) and max_angle > 0 and math.isfinite(max_rate) and max_rate > 0):
        raise ValueError(f"tilt limits must be > 0, got {max_angle} rad, {max_rate} rad/s")
    return ControlSpace(base, index, to_pose, t(0.0), t(float(max_angle)), t(float(max_rate)))
