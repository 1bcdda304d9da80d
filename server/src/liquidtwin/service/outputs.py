"""A session's per-frame outputs as wire messages (docs/service.md "Streams").

``particles`` is a ``foxglove.PointCloud`` in frame ``world`` with float32 fields x, y, z
(m) and speed (m/s), 16 bytes per point; ``overlay`` a ``foxglove.RawImage`` rgb8 in thesis
Fig. 8.10's colours; ``volumes``, ``metrics`` and ``control`` are liquidtwin messages.
"""

from __future__ import annotations

import math

import numpy as np
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf.timestamp_pb2 import Timestamp
from liquidtwin_proto import (ContainerVolume, Header, Metrics, ObjectMesh, OverlayInfo, SceneMeshes, Volumes,
                              pack_array)

from ..session import MODEL_RGB, OBSERVED_RGB, OVERLAP_RGB, pack_rgb

WORLD = "world"
_FIELDS = ("x", "y", "z", "speed")


def timestamp(stamp_ns: int) -> Timestamp:
    """Protobuf Timestamp of ``stamp_ns`` (ns since the Unix epoch)."""
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return Timestamp(seconds=sec, nanos=nsec)


def particles_cloud(positions: np.ndarray, speeds: np.ndarray, stamp_ns: int) -> PointCloud:
    """PointCloud of (N, 3) float32 positions (m, world) and (N,) float32 speeds (m/s)."""
    pos = np.asarray(positions, np.float32).reshape(-1, 3)
    spd = np.asarray(speeds, np.float32).reshape(-1, 1)
    if len(pos) != len(spd):
        raise ValueError(f"{len(pos)} positions but {len(spd)} speeds")
    data = np.ascontiguousarray(np.concatenate([pos, spd], axis=1), dtype="<f4")
    msg = PointCloud(frame_id=WORLD, point_stride=16, data=data.tobytes())
    msg.timestamp.CopyFrom(timestamp(stamp_ns))
    msg.pose.orientation.w = 1.0
    for i, name in enumerate(_FIELDS):
        msg.fields.add(name=name, offset=4 * i, type=PackedElementField.FLOAT32)
    return msg


def volumes_message(header: Header, volumes: dict, mask_volumes: dict | None = None) -> Volumes:
    """Volumes of {container: ml}; ``mask_volumes`` {container: ml or None} fills ``mask_ml``
    (the model-based estimate, SPEC §5; left unset for None)."""
    msg = Volumes(header=header)
    msg.containers.extend(container_volumes(volumes, mask_volumes))
    return msg


def container_volumes(volumes: dict, mask_volumes: dict | None = None) -> list[ContainerVolume]:
    """[ContainerVolume] of {container: ml} (for SessionStatus), with ``mask_ml`` from
    ``mask_volumes`` {container: ml or None} where it is known."""
    out = []
    for n, v in volumes.items():
        m = (mask_volumes or {}).get(n)
        out.append(ContainerVolume(name=n, ml=float(v)) if m is None else
                   ContainerVolume(name=n, ml=float(v), mask_ml=float(m)))
    return out


def overlay_image(rgb: np.ndarray, camera: str, stamp_ns: int) -> RawImage:
    """rgb8 RawImage of an (H, W, 3) uint8 overlay, frame_id = the camera."""
    img = np.ascontiguousarray(rgb, dtype=np.uint8)
    h, w = img.shape[:2]
    msg = RawImage(frame_id=camera, width=w, height=h, encoding="rgb8", step=3 * w, data=img.tobytes())
    msg.timestamp.CopyFrom(timestamp(stamp_ns))
    return msg


def overlay_info(camera: str, corr) -> OverlayInfo:
    """OverlayInfo (colours and pixel counts) of a CorrectionResult."""
    return OverlayInfo(camera=camera, observed_only_rgb=pack_rgb(OBSERVED_RGB), model_only_rgb=pack_rgb(MODEL_RGB),
                       overlap_rgb=pack_rgb(OVERLAP_RGB), observed_px=int(corr.observed_px),
                       model_px=int(corr.model_px), overlap_px=int(corr.overlap_px))


def metrics_message(header: Header, *, input_seq: int, frame, particles: int, counters: dict, lag_ms: float,
                    correction=None, camera: str = "") -> Metrics:
    """Metrics of one processed frame.

    Args:
      frame: the engine's FrameResult; correction: its CorrectionResult or None (iou NaN).
      counters: frames_in, frames_done, dropped_stale, dropped_out_of_order, rejected.
      lag_ms: receive-to-publish time of the frame, ms.
    """
    m = Metrics(header=header, input_seq=int(input_seq), sim_time_s=float(frame.sim_time_s),
                iou=float(correction.iou) if correction is not None else math.nan, step_ms=float(frame.step_ms),
                correction_ms=float(correction.correction_ms) if correction is not None else 0.0,
                lag_ms=float(lag_ms), sim_lag_s=float(frame.sim_lag_s), particles=int(particles),
                steps=int(frame.steps))
    for k in ("frames_in", "frames_done", "dropped_stale", "dropped_out_of_order", "rejected"):
        setattr(m, k, int(counters.get(k, 0)))
    if correction is not None:
        m.overlay.CopyFrom(overlay_info(camera, correction))
    return m


def scene_meshes(header: Header, meshes: dict) -> SceneMeshes:
    """SceneMeshes of {name: ((V, 3) float32 m, (F, 3) uint32, is_container)}."""
    msg = SceneMeshes(header=header)
    for name, (v, f, container) in meshes.items():
        msg.objects.append(ObjectMesh(name=name, vertices=pack_array(np.asarray(v, np.float32)),
                                      faces=pack_array(np.asarray(f, np.uint32)), container=bool(container)))
    return msg
