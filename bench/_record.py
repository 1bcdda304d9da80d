"""What a bench script does with each result: stamp it with the commit and the date, print
it as one JSON line and append it to bench/history.jsonl (unless ``history`` is False)."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

HISTORY = Path(__file__).resolve().with_name("history.jsonl")


def commit() -> str:
    """Short hash of the checkout's HEAD ("" outside git)."""
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          cwd=HISTORY.parent).stdout.strip()


def emit(rec: dict, history: bool = True) -> dict:
    rec = {**rec, "commit": commit(), "date": time.strftime("%Y-%m-%d")}
    print(json.dumps(rec), flush=True)
    if history:
        with HISTORY.open("a") as f:
            f.write(json.dumps(rec) + "\n")
    return rec
