"""Time mesh_sdf_grid builds (cache off): a revolved cup, an icosphere, optionally the catalogue.

    OMP_NUM_THREADS=1 .venv/bin/python bench/sdf_build.py [--threads N] [--device cuda]
        [--sections 256] [--cell 0.00075] [--catalogue]

Prints one JSON line per mesh: triangles, grid shape, nodes, wall and CPU seconds, nodes/s.
On a shared machine the CPU seconds are the steadier figure.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch
import trimesh

from liquidtwin.geometry.mesh_sdf import mesh_sdf_grid
from liquidtwin.scenes.shapes import cup_mesh


def revolved_cup(radius=0.04, height=0.10, wall=0.003, sections=64) -> trimesh.Trimesh:
    """Open-top cup (inner radius, total height, wall, m) standing on y = 0, opening up (+y)."""
    return cup_mesh(radius, height, wall, sections)


def _time(what: str, mesh, thickness: float, args) -> None:
    t, c = time.perf_counter(), time.process_time()
    g = mesh_sdf_grid(mesh, thickness, name=what, cache_dir=False, device=args.device)
    if g.values.is_cuda:
        torch.cuda.synchronize()
    s, cpu = time.perf_counter() - t, time.process_time() - c
    n = g.values.numel()
    print(json.dumps({"what": what, "triangles": len(mesh.faces), "wall_m": thickness,
                      "shape": list(g.values.shape), "nodes": n, "seconds": round(s, 2),
                      "cpu_seconds": round(cpu, 2), "nodes_per_s": round(n / s),
                      "threads": args.threads, "device": str(g.values.device)}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default=None)
    ap.add_argument("--sections", type=int, default=256, help="cup facets around the axis")
    ap.add_argument("--cell", type=float, default=0.00075, help="m; the wall is 4 cells")
    ap.add_argument("--catalogue", action="store_true", help="also every geometry.meshes model")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    _time("cup", revolved_cup(sections=args.sections), 4 * args.cell, args)
    _time("icosphere", trimesh.creation.icosphere(4, radius=0.05), 4 * args.cell, args)
    if args.catalogue:
        from liquidtwin.geometry.meshes import MODELS, build
        for name in MODELS:
            obj = build(name)
            _time(name, obj.mesh, obj.wall, args)


if __name__ == "__main__":
    main()
