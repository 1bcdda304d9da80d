"""The committed generated code matches what proto/generate.py makes from the .proto."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGE_DIR = ROOT / "proto" / "src" / "liquidtwin_proto"


def test_generated_code_is_up_to_date(tmp_path):
    run = subprocess.run(
        [sys.executable, str(ROOT / "proto" / "generate.py"), "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120,
    )
    assert run.returncode == 0, run.stderr
    fresh = sorted(p.name for p in (tmp_path / "liquidtwin_proto").iterdir())
    committed = sorted(p.name for p in PACKAGE_DIR.glob("*_pb2.py*"))
    assert fresh == committed, "generated modules and .proto files disagree; run `make proto`"
    stale = [name for name in fresh
             if (tmp_path / "liquidtwin_proto" / name).read_bytes()
             != (PACKAGE_DIR / name).read_bytes()]
    assert stale == [], f"stale generated files {stale}; run `make proto` and commit them"


def test_generated_code_is_marked_generated():
    head = (PACKAGE_DIR / "liquidtwin_pb2.py").read_text().splitlines()[:5]
    assert any("DO NOT EDIT" in line for line in head)
    assert any("source: liquidtwin_proto/liquidtwin.proto" in line for line in head)
