"""Regenerate the golden recordings checked into tests/server/data/.

    .venv/bin/python tests/server/data/make_golden.py [OUT_DIR]

The golden file is a quick ``pour_dump`` (seed 7, noisy sensors, no hidden effect) as
``liquidtwin generate --scene pour_dump --quick --seed 7`` writes it. Regenerate it (and
commit the result) whenever the recording format or the generator changes on purpose;
``tests/server/test_generate.py`` checks that a fresh run still matches it.

A second, different scene, a quick ``pour_hold`` (seed 7), is written beside it for the
service tests that stream two sessions at once (``tests/service/test_stream_sessions.py``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

SCENE, SEED = "pour_dump", 7
NAME = "golden_pour_dump.mcap"
SECOND_SCENE, SECOND_SEED = "pour_hold", 7
SECOND_NAME = "golden_pour_hold.mcap"


def make(out_dir: Path) -> Path:
    from liquidtwin.generate import generate
    torch.set_num_threads(1)
    out = Path(out_dir) / NAME
    generate(SCENE, out, seed=SEED, quick=True)
    return out


def make_second(out_dir: Path) -> Path:
    """The second golden recording (quick pour_hold, seed 7)."""
    from liquidtwin.generate import generate
    torch.set_num_threads(1)
    out = Path(out_dir) / SECOND_NAME
    generate(SECOND_SCENE, out, seed=SECOND_SEED, quick=True)
    return out


if __name__ == "__main__":
    where = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).parent
    print(make(where))
    print(make_second(where))
