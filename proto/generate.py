#!/usr/bin/env python3
"""Regenerate liquidtwin_proto's Python modules from its .proto files.

The .proto files under src/liquidtwin_proto/ are the single source of the wire contract;
the *_pb2.py / *_pb2.pyi modules beside them are produced here, by the protoc bundled with
grpcio-tools (a dev dependency pinned in requirements.lock, so every machine generates
byte-identical output), and committed. Never edit the generated files by hand.

Usage:
    python proto/generate.py            # rewrite the committed modules in place
    python proto/generate.py --out DIR  # write them under DIR instead (used by the staleness test)
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parent / "src"
PACKAGE = "liquidtwin_proto"


def proto_files() -> list[Path]:
    """All .proto files of the package, sorted, as paths relative to ``SRC``."""
    return sorted(p.relative_to(SRC) for p in (SRC / PACKAGE).glob("*.proto"))


def generate(out_dir: Path) -> list[Path]:
    """Run protoc on every .proto file; write ``out_dir/liquidtwin_proto/*_pb2.py[i]``.

    Returns the generated files. Raises RuntimeError when grpcio-tools is missing or
    protoc reports an error.
    """
    try:
        from grpc_tools import protoc
        import grpc_tools
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise RuntimeError(
            "grpcio-tools is not installed; run `make venv` (it is pinned in requirements.lock)"
        ) from exc

    files = proto_files()
    if not files:
        raise RuntimeError(f"no .proto files under {SRC / PACKAGE}")
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / PACKAGE).mkdir(exist_ok=True)
    well_known = Path(grpc_tools.__file__).parent / "_proto"
    args = [
        "protoc",
        f"-I{SRC}",
        f"-I{well_known}",
        f"--python_out={out_dir}",
        f"--pyi_out={out_dir}",
        *(str(f) for f in files),
    ]
    # protoc records each file's path as given: run it from SRC with relative names so the
    # generated code names `liquidtwin_proto/x.proto` whatever the checkout's location.
    cwd = os.getcwd()
    os.chdir(SRC)
    try:
        rc = protoc.main(args)
    finally:
        os.chdir(cwd)
    if rc != 0:
        raise RuntimeError(f"protoc failed with exit code {rc}")
    stems = [f.with_suffix("").name for f in files]
    return [out_dir / PACKAGE / f"{s}_pb2{ext}" for s in stems for ext in (".py", ".pyi")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out",
        type=Path,
        default=SRC,
        help="directory that receives liquidtwin_proto/*_pb2.py[i] (default: proto/src)",
    )
    args = parser.parse_args(argv)
    try:
        written = generate(args.out.resolve())
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
