"""What a streaming run achieved: frames answered, IOU, volumes, latency, drops.

:class:`Tally` collects as frames are sent and outputs arrive; :meth:`Tally.summary`
gives a :class:`StreamSummary` that prints as a table or serialises to JSON.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from .messages import Output


@dataclass(frozen=True)
class StreamSummary:
    """Result of streaming frames to a session.

    Attributes:
        session_id, rate, tracking: what ran ("realtime"/"max", tracking mode name).
        frames_sent: poses samples (frames) published.
        frames_answered: distinct sent frame stamps that got a particles output.
        frames_timed_out: frames whose particles did not come within the frame timeout
            (``max`` rate only; in ``realtime`` the server may drop frames instead).
        mean_iou: mean Metrics.iou over frames that had a mask (None when none had).
        iou_frames: how many metrics carried a finite IOU.
        final_volumes_ml: {container: ml} of the last Volumes output (particle count).
        final_mask_volumes_ml: {container: ml} of its model-based estimates (``mask_ml``,
            from the masks alone; containers whose mask estimate is unset are left out).
        latency_ms_p50, latency_ms_p99, latency_ms_max: publish of a frame's poses →
            receipt of its particles, ms (None when no frame was answered).
        dropped_stale, dropped_out_of_order, rejected: the server's counters from the last
            Metrics (frames superseded in its inbox, samples not newer than the last
            accepted, invalid samples).
        outputs: outputs received per stream. lost_outputs: outputs the client dropped or
            could not decode.
        wall_s: seconds from the first frame sent to the last output awaited.
    """

    session_id: str
    rate: str
    tracking: str
    frames_sent: int
    frames_answered: int
    frames_timed_out: int
    mean_iou: float | None
    iou_frames: int
    final_volumes_ml: dict[str, float]
    latency_ms_p50: float | None
    latency_ms_p99: float | None
    latency_ms_max: float | None
    dropped_stale: int
    dropped_out_of_order: int
    rejected: int
    outputs: dict[str, int] = field(default_factory=dict)
    lost_outputs: int = 0
    wall_s: float = 0.0
    final_mask_volumes_ml: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict:
        """A JSON-ready dict of every field."""
        return asdict(self)


class Tally:
    """Counts sent frames and received outputs (call from one thread)."""

    def __init__(self):
        self.sent_ns: dict[int, int] = {}        # frame stamp -> wall ns its poses went out
        self.answered_ns: dict[int, int] = {}    # frame stamp -> wall ns its particles came
        self.timed_out = 0
        self.ious: list[float] = []
        self.volumes: dict[str, float] = {}
        self.mask_volumes: dict[str, float] = {}
        self.counters = {"dropped_stale": 0, "dropped_out_of_order": 0, "rejected": 0}
        self.outputs: dict[str, int] = {}
        self._volume_stamp = -1
        self._seen: set[tuple[int, str]] = set()

    def sent(self, stamp_ns: int, wall_ns: int) -> None:
        """A frame (poses sample) of ``stamp_ns`` was published at wall time ``wall_ns``."""
        self.sent_ns.setdefault(int(stamp_ns), int(wall_ns))

    def add(self, out: Output) -> None:
        """Account for one received output."""
        self.outputs[out.stream] = self.outputs.get(out.stream, 0) + 1
        stamp = int(out.header.stamp_ns)
        self._seen.add((stamp, out.stream))
        if out.stream == "particles":
            self.answered_ns.setdefault(stamp, int(out.received_ns))
        elif out.stream == "metrics":
            m = out.message
            if math.isfinite(m.iou):
                self.ious.append(float(m.iou))
            for name in self.counters:
                self.counters[name] = max(self.counters[name], int(getattr(m, name)))
        elif out.stream == "volumes" and stamp >= self._volume_stamp:
            self._volume_stamp = stamp
            self.volumes = {c.name: float(c.ml) for c in out.message.containers}
            self.mask_volumes = {c.name: float(c.mask_ml) for c in out.message.containers if c.HasField("mask_ml")}

    def is_answered(self, stamp_ns: int) -> bool:
        """True once particles for frame ``stamp_ns`` arrived."""
        return int(stamp_ns) in self.answered_ns

    def has(self, stamp_ns: int, stream: str) -> bool:
        """True once an output of ``stream`` for frame ``stamp_ns`` arrived."""
        return (int(stamp_ns), stream) in self._seen

    def summary(self, session_id: str, rate: str, tracking: str, *, lost_outputs: int = 0,
                wall_s: float = 0.0) -> StreamSummary:
        """The run so far as a StreamSummary."""
        lat = np.array([(self.answered_ns[s] - t) * 1e-6 for s, t in self.sent_ns.items()
                        if s in self.answered_ns], dtype=np.float64)
        pct = (lambda q: float(np.percentile(lat, q))) if lat.size else (lambda q: None)
        return StreamSummary(
            session_id=session_id, rate=rate, tracking=tracking,
            frames_sent=len(self.sent_ns),
            frames_answered=sum(1 for s in self.sent_ns if s in self.answered_ns),
            frames_timed_out=self.timed_out,
            mean_iou=float(np.mean(self.ious)) if self.ious else None,
            iou_frames=len(self.ious), final_volumes_ml=dict(self.volumes),
            latency_ms_p50=pct(50), latency_ms_p99=pct(99),
            latency_ms_max=float(lat.max()) if lat.size else None,
            outputs=dict(sorted(self.outputs.items())), lost_outputs=int(lost_outputs),
            wall_s=float(wall_s), final_mask_volumes_ml=dict(self.mask_volumes), **self.counters)


def format_table(s: StreamSummary) -> str:
    """The summary as an aligned two-column text table."""
    def num(v, fmt):
        return "-" if v is None else format(v, fmt)

    rows = [
        ("session", s.session_id), ("rate / tracking", f"{s.rate} / {s.tracking}"),
        ("frames sent / answered", f"{s.frames_sent} / {s.frames_answered}"),
        ("frames timed out", str(s.frames_timed_out)),
        ("mean IOU", f"{num(s.mean_iou, '.3f')}  ({s.iou_frames} frames with a mask)"),
    ]
    for name, ml in sorted(s.final_volumes_ml.items()):
        m = s.final_mask_volumes_ml.get(name)
        rows.append((f"final volume {name}", f"{ml:.2f} ml particles, {num(m, '.2f')} ml from masks"))
    rows += [
        ("latency publish→particles", f"p50 {num(s.latency_ms_p50, '.1f')} ms, "
         f"p99 {num(s.latency_ms_p99, '.1f')} ms, max {num(s.latency_ms_max, '.1f')} ms"),
        ("dropped stale / out-of-order", f"{s.dropped_stale} / {s.dropped_out_of_order}"),
        ("rejected inputs", str(s.rejected)),
        ("outputs", ", ".join(f"{k} {v}" for k, v in s.outputs.items()) or "-"),
        ("outputs lost by the client", str(s.lost_outputs)),
        ("wall time", f"{s.wall_s:.2f} s"),
    ]
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k.ljust(width)}  {v}" for k, v in rows)
