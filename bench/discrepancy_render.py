"""How long the discrepancy analysis takes to draw a rollout, first time and re-drawn (stop 60).

    OMP_NUM_THREADS=1 .venv/bin/python bench/discrepancy_render.py REC.mcap [--redraws 4]

Rolls the recording's stated model out once (``discrepancy.rollout.Simulator``, not timed),
then times ``Simulator.render`` at every mask frame: the first drawing, ``--redraws`` re-draws
for rotated cameras (camera_offset) and as many for time offsets (time_offset), the way the
observation candidates re-draw a kept rollout. Prints seconds per drawing. To compare two
versions, run it alternately with ``PYTHONPATH`` set to each version's ``server/src`` (this
machine's speed drifts by 10-20 % within minutes, so only alternating runs compare).
"""

from __future__ import annotations

import argparse
import time

import torch


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("recording")
    p.add_argument("--redraws", type=int, default=4, help="re-draws of each kind (default 4)")
    a = p.parse_args()
    torch.set_num_threads(1)
    from liquidtwin.discrepancy.episode import load_episode
    from liquidtwin.discrepancy.model import Extension
    from liquidtwin.discrepancy.rollout import Simulator

    sim = Simulator(load_episode(a.recording))
    traj = sim.rollout(Extension())
    t = time.perf_counter()
    sim.render(traj)
    first = time.perf_counter() - t
    angles = [(1.2, 0.0), (-1.2, 0.0), (0.0, 1.2), (0.0, -1.2)]
    offsets = [0.05, -0.05, 0.1, -0.1]
    out = {"first": first}
    for name, exts in (("camera", [Extension("camera_offset", {"rx": angles[i % 4][0] * (1 + i // 4), "ry": angles[i % 4][1], "rz": 0.0})
                                   for i in range(a.redraws)]),
                       ("time", [Extension("time_offset", {"value": offsets[i % 4] * (1 + i // 4)}) for i in range(a.redraws)])):
        t = time.perf_counter()
        for e in exts:
            sim.render(traj, ext=e)
        out[f"{name} re-draw"] = (time.perf_counter() - t) / len(exts)
    print(f"{len(traj.x[0])} particles, {len(sim.ep.frame_t)} mask frames; s per drawing: "
          + ", ".join(f"{k} {v:.3f}" for k, v in out.items()))


if __name__ == "__main__":
    main()
