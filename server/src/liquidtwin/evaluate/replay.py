"""Feed a recording to a :class:`~liquidtwin.session.SessionEngine` the way the server does.

Per pose sample: advance to its stamp (session time = stamp − first stamp); when a mask is
stamped with the same time, correct with it. The analysis reads the recording only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from liquidtwin_proto import liquidtwin_pb2 as pb

#: Tracking-mode names used on command lines and in tables → proto enum.
MODES = {"open_loop": pb.OPEN_LOOP, "map_filter": pb.MAP_FILTER, "warp_field": pb.WARP_FIELD,
         "spnets_perception": pb.SPNETS_PERCEPTION}


@dataclass
class Replay:
    """What one replay measured. Per mask frame: ``t_s`` session time, ``iou`` model vs
    observed before the correction, ``observed_px``; ``engine`` is left at the last frame."""

    engine: object
    camera: str
    t_s: list = field(default_factory=list)
    iou: list = field(default_factory=list)
    observed_px: list = field(default_factory=list)

    def mean_iou(self, min_px: int = 50) -> float | None:
        """Mean IOU over frames whose observed mask has ≥ ``min_px`` liquid pixels."""
        v = [i for i, n in zip(self.iou, self.observed_px) if n >= min_px]
        return float(np.mean(v)) if v else None


def engine_for(rec, tracking: str = "open_loop", *, spec: pb.SessionSpec | None = None, **spec_fields):
    """A SessionEngine for ``rec`` (its scene and first camera's calibration)."""
    from ..session import SessionEngine
    if tracking not in MODES:
        raise ValueError(f"unknown tracking mode {tracking!r}; known: {', '.join(MODES)}")
    spec = spec if spec is not None else pb.SessionSpec(scene=rec.spec, tracking=MODES[tracking], **spec_fields)
    eng = SessionEngine.create(spec)
    for name, cam in rec.cameras.items():
        eng.set_camera(name, K=cam.K, D=cam.D, width=cam.width, height=cam.height, pose=cam.pose)
    return eng


def model_mask(overlay: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels a correction's overlay shows as the model's liquid (model only
    or overlap, :mod:`liquidtwin.session.overlay`'s colours)."""
    from ..session import MODEL_RGB, OVERLAP_RGB
    return np.all(overlay == MODEL_RGB, axis=2) | np.all(overlay == OVERLAP_RGB, axis=2)


def replay(rec, engine, *, camera: str | None = None, frames: int | None = None,
           on_frame: Callable | None = None, reference: np.ndarray | None = None) -> Replay:
    """Run ``engine`` over ``rec``. ``on_frame(i, engine, correction_or_None)`` is called after
    each pose sample (``correction`` is the CorrectionResult when a mask came with it).
    ``reference``: (M, H, W) bool masks, one per mask of ``camera`` in ``rec``, to score the
    model against instead of the masks it is corrected with (e.g. the recorded masks when the
    tracker is fed detected ones)."""
    if rec.spec is None:
        raise ValueError(f"{rec.path}: no /scene in the recording; cannot build the model")
    if not rec.masks:
        raise ValueError(f"{rec.path}: no liquid masks in the recording")
    import torch
    from ..camera import iou as mask_iou
    camera = camera or next(iter(rec.masks))
    stamps, masks = rec.masks[camera]
    if reference is not None and np.shape(reference) != np.shape(masks):
        raise ValueError(f"reference masks {np.shape(reference)} do not match the recording's {np.shape(masks)}")
    out = Replay(engine, camera)
    n = len(rec.pose_times_ns) if frames is None else min(frames, len(rec.pose_times_ns))
    t0 = int(rec.pose_times_ns[0])
    for i in range(n):
        t = int(rec.pose_times_ns[i])
        engine.advance((t - t0) * 1e-9, dict(zip(rec.object_names, rec.poses[i])))
        j = int(np.searchsorted(stamps, t))
        c = None
        if j < len(stamps) and stamps[j] == t:
            c = engine.correct(camera, masks[j])
            out.t_s.append((t - t0) * 1e-9)
            if reference is None:
                out.iou.append(float(c.iou))
                out.observed_px.append(int(c.observed_px))
            else:
                ref = np.asarray(reference[j], bool)
                out.iou.append(float(mask_iou(torch.from_numpy(model_mask(c.overlay)), torch.from_numpy(ref))))
                out.observed_px.append(int(ref.sum()))
        if on_frame is not None:
            on_frame(i, engine, c)
    return out
