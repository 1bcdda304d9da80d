"""What solving a pour's falls costs a session: the simulation steps' wall time per pose
sample when a recording is replayed open loop at its stated solver iterations and at the
count its falls need (``scenes.spec.impact_iterations``, as ``liquidtwin serve
--solve-impacts`` and ``evaluate tracking --iterations impact`` give it), on one thread.

    OMP_NUM_THREADS=1 .venv/bin/python bench/impact_cost.py REC.mcap [REC2.mcap …] [--frames 120]

Per recording and count: particles, median and mean step time per pose sample (ms; the
steps ``SessionEngine.advance`` takes to reach each sample: 2 at 60 Hz samples and 120 Hz
steps), and the ratio impact / stated. Only the steps are timed (``FrameResult.step_ms``),
not the correction or drawing. Appends one record per recording to bench/history.jsonl
unless ``--no-history``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from _record import emit


def step_times(rec, frames: int) -> tuple[int, list[float]]:
    """(particles, step ms per pose sample) of an open-loop run of ``rec`` over ``frames``
    pose samples (the first is the start and is not timed)."""
    from liquidtwin.evaluate.replay import engine_for
    engine = engine_for(rec, "open_loop")
    t0 = int(rec.pose_times_ns[0])
    out = []
    for i in range(min(frames, len(rec.pose_times_ns))):
        r = engine.advance((int(rec.pose_times_ns[i]) - t0) * 1e-9, dict(zip(rec.object_names, rec.poses[i])))
        if i and r.steps:
            out.append(r.step_ms)
    return engine.n_particles, out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("recordings", type=Path, nargs="+", metavar="REC.mcap")
    p.add_argument("--frames", type=int, default=120, help="pose samples replayed (default: %(default)s)")
    p.add_argument("--no-history", action="store_true", help="do not append to bench/history.jsonl")
    args = p.parse_args()
    if args.frames < 2:
        raise SystemExit("--frames must be >= 2")
    torch.set_num_threads(1)
    from liquidtwin.evaluate.cli import with_model_options
    from liquidtwin.recordings import read_recording
    print(f"{'recording':34s} {'particles':>9s} {'stated':>6s} {'ms':>7s} {'impact':>6s} {'ms':>7s} {'ratio':>6s}")
    for path in args.recordings:
        rows = {}
        for mode in (None, "impact"):
            rec = with_model_options(read_recording(path, images=False), mode)
            n, ms = step_times(rec, args.frames)
            rows[mode] = (int(rec.spec.simulation.iterations), n, float(np.median(ms)), float(np.mean(ms)))
        (k0, n, m0, a0), (k1, _, m1, a1) = rows[None], rows["impact"]
        print(f"{path.stem:34s} {n:9d} {k0:6d} {m0:7.1f} {k1:6d} {m1:7.1f} {m1 / m0:6.2f}")
        emit({"what": "impact_cost", "recording": path.name, "particles": n, "frames": args.frames,
              "stated_iterations": k0, "impact_iterations": k1, "stated_step_ms_median": m0,
              "impact_step_ms_median": m1, "stated_step_ms_mean": a0, "impact_step_ms_mean": a1,
              "ratio": m1 / m0}, history=not args.no_history)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
