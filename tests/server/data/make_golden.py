"""Regenerate the golden recording checked into tests/server/data/.

    .venv/bin/python tests/server/data/make_golden.py [OUT_DIR]

The golden file is a quick ``pour_dump`` (seed 7, noisy sensors, no hidden effect) as
``liquidtwin generate --scene pour_dump --quick --seed 7`` writes it. Regenerate it (and
commit the result) whenever the recording format or the generator changes on purpose;
``tests/server/test_generate.py`` checks that a fresh run still matches it.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

SCENE, SEED = "pour_dump", 7
NAME = "golden_pour_dump.mcap"


def make(out_dir: Path) -> Path:
    from liquidtwin.generate import generate
    torch.set_num_threads(1)
    out = Path(out_dir) / NAME
    generate(SCENE, out, seed=SEED, quick=True)
    return out


if __name__ == "__main__":
    print(make(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).parent))
