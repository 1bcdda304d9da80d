"""Time ``mesh_sdf_grid`` builds (no cache) for a revolved cup and an icosphere.

    OMP_NUM_THREADS=1 .venv/bin/python bench/sdf_build.py [--threads N] [--device cuda] [--sections 64]

Prints one JSON line per mesh: triangles, grid shape, nodes, seconds, nodes/s.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch
import trimesh

from liquidtwin.geometry.mesh_sdf import mesh_sdf_grid


def revolved_cup(radius=0.04, height=0.10, wall=0.003, sections=64) -> trimesh.Trimesh:
    """Open-top cup (inner radius, total height, wall, m) standing on y = 0, opening up (+y)."""
    r, h, w = radius, height, wall
    profile = np.array([[0, 0], [r + w, 0], [r + w, h], [r, h], [r, w], [0, w]])
    mesh = trimesh.creation.revolve(profile[::-1], sections=sections)  # about z, outward normals
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default=None)
    ap.add_argument("--sections", type=int, default=64)
    ap.add_argument("--cell", type=float, default=0.00075)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    cases = {"cup": revolved_cup(sections=args.sections),
             "icosphere": trimesh.creation.icosphere(4, radius=0.05)}
    for what, mesh in cases.items():
        t = time.perf_counter()
        g = mesh_sdf_grid(mesh, thickness=4 * args.cell, name=what, cache_dir=False, device=args.device)
        if args.device and args.device.startswith("cuda"):
            torch.cuda.synchronize()
        s = time.perf_counter() - t
        n = g.values.numel()
        print(json.dumps({"what": what, "triangles": len(mesh.faces), "shape": list(g.values.shape), "nodes": n,
                          "seconds": round(s, 2), "nodes_per_s": round(n / s), "threads": args.threads,
                          "device": str(g.values.device)}))


if __name__ == "__main__":
    main()
