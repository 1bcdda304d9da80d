"""The SPNets step of two versions of the code, timed side by side on this machine.

    OMP_NUM_THREADS=1 .venv/bin/python bench/step_versions.py --old OLD/server/src [--new server/src]
        [--particles 2000 8000 32000] [--steps 20] [--rounds 3] [--pour-steps 300] [--no-history]

How to get OLD: ``git worktree add /tmp/old <commit>`` and build its extension in place
(``cd /tmp/old/server && python setup.py build_ext --inplace``, with this checkout's
``.venv/bin/python``). Each measurement is a fresh process with ``PYTHONPATH`` set to one
version's ``src``, one torch thread, and the versions alternate within every round, so a
machine that is slower for a while slows both: this machine's speed drifts by 10–20 % from
minute to minute, more than many changes are worth.

Measures, per version:
- ``liquidtwin.bench.forward`` (the basin scene of ``liquidtwin bench``: a block of ~N
  particles released in an open box, K = 3, dt 1/120 s; ms per step after 3 warm-up steps);
- with ``--pour-steps S`` (0 skips it), the first S steps of the full-size pour of
  ``bench/pour_rollout.py`` (cup 90 %, 3.6k particles, 6 iterations; the recording must exist:
  run ``bench/pour_rollout.py`` once to generate it).
Prints the median of the rounds for each, the new/old speed ratio, and appends one record per
measurement kind to bench/history.jsonl.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from _record import emit

HERE = Path(__file__).resolve().parent
POUR = HERE / "results" / "pour_rollout_cup90_s4.mcap"

_FORWARD = """
import json, sys
from liquidtwin.bench import forward
r = forward(int(sys.argv[1]), int(sys.argv[2]), "auto")
print(json.dumps({"ms": 1e3 * r["seconds"] / r["steps"], "particles": r["particles"]}))
"""

_POUR = """
import json, sys, time
from pathlib import Path
from liquidtwin.discrepancy.episode import load_episode
from liquidtwin.discrepancy.model import Extension
from liquidtwin.discrepancy.rollout import Simulator
sim = Simulator(load_episode(Path(sys.argv[1])))
steps = min(int(sys.argv[2]), sim.steps)
t = time.perf_counter()
sim.rollout(Extension(), steps=steps)
print(json.dumps({"ms": 1e3 * (time.perf_counter() - t) / steps, "particles": None}))
"""


def _run(src: Path, code: str, *args) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", code, *map(str, args)], env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{src}: measurement failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--old", type=Path, required=True, help="the old version's server/src (with its _native built)")
    p.add_argument("--new", type=Path, default=HERE.parent / "server" / "src", help="the new version's server/src")
    p.add_argument("--particles", type=int, nargs="*", default=[2000, 8000, 32000], help="basin sizes (none: skip the basin)")
    p.add_argument("--steps", type=int, default=20, help="timed basin steps per measurement")
    p.add_argument("--rounds", type=int, default=3, help="measurements per version (alternating)")
    p.add_argument("--pour-steps", type=int, default=300, help="steps of the full-size pour (0: skip it)")
    p.add_argument("--no-history", action="store_true", help="print only; do not append to bench/history.jsonl")
    a = p.parse_args()
    for src in (a.old, a.new):
        if not (src / "liquidtwin" / "__init__.py").exists():
            raise SystemExit(f"{src} is not a server/src directory (no liquidtwin/__init__.py)")
    if a.pour_steps and not POUR.exists():
        raise SystemExit(f"{POUR} is missing: run bench/pour_rollout.py once to generate it, or pass --pour-steps 0")
    jobs = [(f"basin {n}", _FORWARD, (n, a.steps)) for n in a.particles]
    if a.pour_steps:
        jobs.append((f"pour {a.pour_steps} steps", _POUR, (POUR, a.pour_steps)))
    for name, code, args in jobs:
        ms = {"old": [], "new": []}
        particles = None
        for r in range(a.rounds):
            for which in (("old", "new") if r % 2 == 0 else ("new", "old")):
                out = _run(getattr(a, which), code, *args)
                ms[which].append(out["ms"])
                particles = out["particles"] or particles
            print(f"  {name}: round {r + 1}/{a.rounds} old {ms['old'][-1]:.1f} ms, new {ms['new'][-1]:.1f} ms",
                  file=sys.stderr, flush=True)
        old, new = statistics.median(ms["old"]), statistics.median(ms["new"])
        emit({"what": "step_versions", "case": name, "particles": particles, "old_src": str(a.old),
              "old_ms_per_step": round(old, 2), "new_ms_per_step": round(new, 2), "speedup": round(old / new, 3),
              "old_rounds_ms": [round(v, 2) for v in ms["old"]], "new_rounds_ms": [round(v, 2) for v in ms["new"]],
              "threads": 1}, history=not a.no_history)


if __name__ == "__main__":
    main()
