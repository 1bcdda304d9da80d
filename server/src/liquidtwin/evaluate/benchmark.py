"""The generated pouring benchmark the evaluations share (thesis ch. 7.5 mirrored).

Cases: source ∈ {cup, bottle} × fill ∈ {30, 60, 90 %} (+ empty for fill inference) ×
trajectory ∈ {partial, hold, dump} × trials. Each case is one ``liquidtwin generate``
recording whose world differs from the model the way a real one would: the world's fluid
parameters are jittered by the seed (``generate.world``), masks and poses are noisy, frames
drop, and one *mild* physical effect (lower quarter of its realistic range) is hidden. The
analysis reads only the recording; the truth sidecar is read by the scoring code alone.

Seeds are derived from ``base_seed`` and the case's position, and written into every result
so a table can be reproduced exactly. Recordings are cached in a data directory keyed by
the case's name, so ``evaluate tracking``, ``fill`` and ``volume`` generate them once.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..procs import map_jobs

#: Effects a benchmark world may carry (mild: lower quarter of the realistic range). Not the
#: geometry, initial-state or observation faults — those are what `discrepancy` is for.
MILD_EFFECTS = ("drag", "wind", "viscosity", "cohesion", "wall_adhesion")
SOURCES = ("cup", "bottle")
FILLS = (0.3, 0.6, 0.9)
KINDS = ("partial", "hold", "dump")


@dataclass(frozen=True)
class Case:
    """One benchmark recording. ``fraction`` 0 is an empty source (fill inference only)."""

    source: str
    fraction: float
    kind: str
    trial: int
    seed: int
    quick: bool
    effect: str | None = None
    effect_value: float | None = None
    rgb: bool = False

    @property
    def name(self) -> str:
        q = "q" if self.quick else "f"
        return (f"{self.kind}-{self.source}-{round(self.fraction * 100):02d}-t{self.trial}-s{self.seed}-{q}"
                + ("-rgb" if self.rgb else ""))

    @property
    def scene(self) -> str:
        return f"pour_{self.kind}"

    def as_dict(self) -> dict:
        return asdict(self) | {"name": self.name}


def mild_effect(name: str, rng: np.random.Generator) -> float:
    """A value in the lower quarter of the effect's first realistic range."""
    from ..generate.effects import EFFECTS
    lo, hi = EFFECTS[name].ranges[0]
    return float(round(rng.uniform(lo, lo + 0.25 * (hi - lo)), 6))


def cases(*, quick: bool, trials: int = 2, sources=SOURCES, fills=FILLS, kinds=KINDS, base_seed: int = 0,
          effects: bool = True, rgb: bool = False) -> list[Case]:
    """The benchmark's cases in a fixed order; seeds ``base_seed + 1000·trial + index``.
    ``rgb``: the recordings carry synthetic RGB frames too (for a detector). Drawing the
    frames' looks uses the seed's random stream, so these are other recordings than the
    plain cases of the same seeds (their names end in ``-rgb``)."""
    for s in sources:
        if s not in SOURCES + ("mug",):
            raise ValueError(f"unknown source {s!r}; the benchmark uses {', '.join(SOURCES)}")
    for f in fills:
        if not 0.0 <= f <= 1.0:
            raise ValueError(f"fill fraction {f} must be in [0, 1]")
    for k in kinds:
        if k not in KINDS:
            raise ValueError(f"unknown trajectory {k!r}; known: {', '.join(KINDS)}")
    out = []
    for trial in range(trials):
        i = 0
        for source in sources:
            for fraction in fills:
                for kind in kinds:
                    seed = base_seed + 1000 * trial + i
                    i += 1
                    eff = val = None
                    if effects:
                        rng = np.random.default_rng([seed, 7919])
                        eff = str(rng.choice(MILD_EFFECTS))
                        val = mild_effect(eff, rng)
                    out.append(Case(source, float(fraction), kind, trial, seed, quick, eff, val, rgb))
    return out


def recording_path(data: Path, case: Case) -> Path:
    return Path(data) / f"{case.name}.mcap"


def _generate_one(args) -> str:
    case_d, data = args
    case = Case(**{k: v for k, v in case_d.items() if k != "name"})
    import torch
    torch.set_num_threads(1)
    from ..generate import generate
    out = recording_path(Path(data), case)
    effects = [(case.effect, case.effect_value)] if case.effect else []
    generate(case.scene, out, effects=effects, seed=case.seed, quick=case.quick, rgb=case.rgb,
             choices={"source": case.source, "fraction": case.fraction})
    meta = out.with_suffix(".case.json")
    meta.write_text(json.dumps(case.as_dict(), indent=2) + "\n")
    return str(out)


def cached(recording: Path) -> bool:
    """Whether a benchmark recording in a ``--data`` cache can be reused: its case file exists
    (written last, so an interrupted generation is redone) and its truth sidecar was written by
    this generator's world (``generate.generator.WORLD_VERSION``), not an older one."""
    from ..generate.generator import WORLD_VERSION
    recording = Path(recording)
    truth = recording.with_suffix(".truth.json")
    if not recording.with_suffix(".case.json").exists() or not truth.exists():
        return False
    try:
        return json.loads(truth.read_text()).get("world_version") == WORLD_VERSION
    except (OSError, ValueError):
        return False


def missing_from(paths: list[Path], *, progress: bool = True) -> list[int]:
    """Indices of ``paths`` to (re)generate; says how many are stale (an older world's)."""
    todo = [i for i, p in enumerate(paths) if not cached(p)]
    stale = [i for i in todo if Path(paths[i]).with_suffix(".case.json").exists()]
    if stale and progress:
        print(f"{len(stale)} cached recording(s) in {Path(paths[stale[0]]).parent} come from an older generator "
              f"world: generating them again", flush=True)
    return todo


def ensure(case_list, data: Path, *, jobs: int = 1, progress: bool = True) -> list[Path]:
    """Generate the recordings of ``case_list`` missing from ``data``, or made there by an older
    world (:func:`cached`), in ``jobs`` processes; return their paths in order."""
    data = Path(data)
    data.mkdir(parents=True, exist_ok=True)
    paths = [recording_path(data, c) for c in case_list]
    missing = [case_list[i] for i in missing_from(paths, progress=progress)]
    generate_all(_generate_one, [(c.as_dict(), str(data)) for c in missing], jobs=jobs,
                 desc="generate benchmark", progress=progress)
    return [recording_path(data, c) for c in case_list]


def generate_all(fn, work: list, *, jobs: int, desc: str, progress: bool) -> None:
    """Run ``fn(item)`` for every item of ``work`` (in ``jobs`` spawned processes when > 1),
    with a progress bar counting finished items."""
    from tqdm import tqdm
    if not work:
        return
    bar = tqdm(total=len(work), desc=desc, unit="rec", disable=not progress)
    for _ in map_jobs(fn, work, jobs, ordered=False, what=desc):     # 1 job: here, in order
        bar.update()
    bar.close()
