"""``liquidtwin bench``: speed and memory of the SPNets step on a realistic scene.

Records (JSON lines, appended to ``bench/history.jsonl`` when run from the repository):
- ``forward``: particle-steps/s of the step at 2k, 8k, 32k particles (K = 3);
- ``forward_backward``: one 10-step differentiable rollout + backward, and its cost
  relative to the forward steps;
- ``rollout_memory``: peak resident memory of a 60-step differentiable rollout at 8k
  particles with and without gradient checkpointing (each in a fresh process);
- ``peer``: a Taichi PBF at the same particle counts when ``bench/peers`` and taichi are
  available (``pip install -r bench/requirements-peers.txt``), with our/peer ratios.
- ``camera_mask``, ``camera_occlusion``, ``camera_splat``: model mask + coverage Φ at
  640×480, occlusion against a cup and a bowl, and a splat forward + backward, for 8k
  particles (``ms``: median of repeats; ``--device`` picks where they run).
Each record has ``what``, ``particles``, ``particle_steps_per_s`` (simulation records),
``peak_mem_bytes``, ``commit``, ``date``. ``--only sim`` / ``--only camera`` runs one group.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import torch

from .scenes import shapes
from .sim import FluidModel, lattice, make_state, rollout, step


def _scene(n: int, backend: str = "auto", h: float = 0.1):
    """~n particles at rest spacing in an open basin, at the thesis's scale (h = 0.1)."""
    spacing = 0.55 * h
    side = (n * 0.75 * spacing**3 / 0.5) ** (1 / 3)  # a block half as tall as it is wide
    wall, gap = 0.3 * h, 0.2 * h
    box = shapes.open_box_grid((side / 2 + gap, side / 2 + gap), side, wall)
    model = FluidModel.create(h, objects=[box], backend=backend, dt=1 / 120, relaxation=4.0)
    x = lattice([-side / 2, wall + gap, -side / 2], [side / 2, wall + gap + side / 2, side / 2], spacing)
    state = make_state(x, poses=torch.tensor([[0, 0, 0, 0, 0, 0, 1.0]]))
    return model, state


def _mean_neighbors(model, state) -> float:
    from .sim import find_neighbors
    return find_neighbors(state.x, None, model.h).num_pairs / len(state.x)


def forward(n: int, steps: int, backend: str) -> dict:
    model, state = _scene(n, backend)
    with torch.no_grad():
        for _ in range(3):  # warm up, let the block start moving
            state = step(model, state)
        t0 = time.perf_counter()
        for _ in range(steps):
            state = step(model, state)
        dt = time.perf_counter() - t0
    n = len(state.x)
    return dict(what="forward", particles=n, steps=steps, seconds=dt, particle_steps_per_s=n * steps / dt,
                neighbors_per_particle=_mean_neighbors(model, state), iterations=model.iterations)


def forward_backward(n: int, steps: int, backend: str) -> dict:
    model, state = _scene(n, backend)
    with torch.no_grad():
        for _ in range(3):
            state = step(model, state)
        t0 = time.perf_counter()
        for _ in range(steps):
            step(model, state)
        fwd = time.perf_counter() - t0
    lv = torch.tensor(60.0, requires_grad=True)
    m = model.with_params(lambda_v=lv)
    t0 = time.perf_counter()
    final, _ = rollout(m, state, steps=steps, keep=False)
    final.x[:, 1].mean().backward()
    both = time.perf_counter() - t0
    n = len(state.x)
    return dict(what="forward_backward", particles=n, steps=steps, seconds=both,
                particle_steps_per_s=n * steps / both, forward_seconds=fwd, ratio_to_forward=both / fwd,
                grad_finite=bool(torch.isfinite(lv.grad)))


def rollout_memory(n: int, steps: int, checkpointed: bool, backend: str) -> dict:
    """Run in a fresh interpreter so the peak resident set belongs to this measurement."""
    code = ("import json,resource,torch;from liquidtwin import bench as b;"
            f"print(json.dumps(b._memory_child({n},{steps},{checkpointed},'{backend}')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _vm(field: str) -> int:
    """A memory figure of this process from /proc/self/status (VmRSS, VmHWM), bytes.

    VmHWM is the peak resident set of this process image; unlike ru_maxrss it is not
    carried over from the parent across exec, so a child measures only itself."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _memory_child(n: int, steps: int, checkpointed: bool, backend: str) -> dict:
    model, state = _scene(n, backend)
    base = _vm("VmRSS")
    lv = torch.tensor(60.0, requires_grad=True)
    t0 = time.perf_counter()
    final, _ = rollout(model.with_params(lambda_v=lv), state, steps=steps, keep=False,
                       checkpoint_steps=checkpointed)
    final.x[:, 1].mean().backward()
    peak = _vm("VmHWM")
    return dict(what="rollout_memory", particles=len(state.x), steps=steps, checkpointed=checkpointed,
                peak_mem_bytes=peak, baseline_bytes=base, rollout_bytes=peak - base,
                seconds=time.perf_counter() - t0, particle_steps_per_s=len(state.x) * steps / (time.perf_counter() - t0))


def peer(n: int) -> dict | None:
    root = Path(__file__).resolve().parents[3]
    if not (root / "bench" / "peers").is_dir():
        return None
    sys.path.insert(0, str(root))
    try:
        from bench.peers import try_run_peer
    except ImportError:
        return None
    res = try_run_peer("taichi", n, steps=60, warmup=10)
    if res:
        res = dict(res, what="peer")
    return res


@functools.lru_cache(maxsize=2)
def _camera_objects(device: str) -> tuple:
    return shapes.cup_grid().to(device), shapes.bowl_grid().to(device)


def _camera_scene(n: int, device: str):
    """n particles: half in a cup, half in and over a bowl 25 cm away; a camera seeing both."""
    from .camera import Camera
    g = torch.Generator().manual_seed(0)

    def rand(k):
        return torch.rand(k, generator=g)
    a, b = n // 2, n - n // 2
    r, th = 0.035 * rand(a) ** 0.5, 6.2832 * rand(a)
    cup_x = torch.stack([r * th.cos(), 0.004 + 0.07 * rand(a), r * th.sin()], 1)
    r, th = 0.07 * rand(b), 6.2832 * rand(b)
    bowl_x = torch.stack([0.25 + r * th.cos(), 0.004 + 0.2 * rand(b), r * th.sin()], 1)
    objects = list(_camera_objects(device))
    poses = torch.tensor([[0, 0, 0, 0, 0, 0, 1.0], [0.25, 0, 0, 0, 0, 0, 1.0]], device=device)
    cam = Camera.look_at((0.12, 0.35, 0.5), (0.12, 0.05, 0), width=640, height=480, fov_y_deg=50)
    return cam, torch.cat([cup_x, bowl_x]).to(device), objects, poses


def _median_ms(fn, repeats: int, device: str) -> float:
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    fn()
    times = []
    for _ in range(repeats):
        sync()
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(1e3 * (time.perf_counter() - t0))
    return sorted(times)[len(times) // 2]


def _reset_peak_rss() -> None:
    """Restart VmHWM from the current resident set (Linux), so a peak measures what follows."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def camera(what: str, n: int = 8000, device: str = "cpu") -> dict:
    """One camera record, "camera_mask", "camera_occlusion" or "camera_splat"; ``ms`` is the
    median wall time of repeats, ``peak_mem_bytes`` the process's peak resident set while
    timing (the SDF grids are built before the peak is reset)."""
    from .camera import coverage, model_mask, splat, visible
    cam, x, objects, poses = _camera_scene(n, device)
    _reset_peak_rss()
    vis = visible(cam, x, objects, poses)
    uv, _ = cam.project(x)
    H, W = cam.height, cam.width
    rec = dict(what=what, particles=len(x), visible_particles=int(vis.sum()), width=W, height=H,
               device=device)
    if what == "camera_mask":
        rec.update(ms=_median_ms(lambda: model_mask(uv, vis, H, W, 5), 30, device), radius_px=5,
                   coverage_ms=_median_ms(lambda: coverage(uv, vis, H, W, 5), 30, device))
    elif what == "camera_occlusion":
        rec.update(ms=_median_ms(lambda: visible(cam, x, objects, poses), 7, device),
                   objects=["cup", "bowl"])
    else:
        xg = x.clone().requires_grad_()

        def fwd_bwd():
            splat(cam.project(xg)[0], vis, H, W, 1.5).sum().backward()
        rec.update(ms=_median_ms(fwd_bwd, 10, device), sigma_px=1.5,
                   forward_ms=_median_ms(lambda: splat(uv, vis, H, W, 1.5), 10, device))
    rec["peak_mem_bytes"] = _vm("VmHWM")
    if device.startswith("cuda"):
        rec["cuda_peak_mem_bytes"] = torch.cuda.max_memory_allocated()
    return rec


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent).stdout.strip() or "unknown"
    except OSError:
        return "unknown"


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(prog="liquidtwin bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--particles", type=int, nargs="+", default=[2000, 8000, 32000])
    p.add_argument("--steps", type=int, default=30, help="timed forward steps per size")
    p.add_argument("--backend", default="auto", choices=["auto", "torch", "fused"])
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: all cores)")
    p.add_argument("--no-memory", action="store_true", help="skip the 60-step memory runs")
    p.add_argument("--no-peer", action="store_true", help="skip the Taichi peer")
    p.add_argument("--only", choices=["sim", "camera"], default=None,
                   help="run one group of records (default: all)")
    p.add_argument("--device", default="cpu",
                   help="torch device for the camera records (default: cpu)")
    p.add_argument("--out", type=Path, default=None, help="write the records as JSON here")
    p.add_argument("--history", type=Path, default=Path(__file__).resolve().parents[3] / "bench" / "history.jsonl",
                   help="append records to this JSON-lines file (default bench/history.jsonl)")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    from tqdm import tqdm
    jobs = [("forward", n) for n in a.particles] + [("forward_backward", 8000 if 8000 in a.particles else a.particles[0])]
    mem_n = 8000 if 8000 in a.particles else a.particles[0]
    if not a.no_memory:
        jobs += [("rollout_memory", False), ("rollout_memory", True)]
    if not a.no_peer:
        jobs += [("peer", n) for n in a.particles]
    camera_jobs = [(w, a.device) for w in ("camera_mask", "camera_occlusion", "camera_splat")]
    jobs = {"camera": camera_jobs, "sim": jobs}.get(a.only, jobs + camera_jobs)
    records = []
    for what, arg in tqdm(jobs, desc="bench", unit="run"):
        if what == "forward":
            r = forward(arg, a.steps, a.backend)
        elif what == "forward_backward":
            r = forward_backward(arg, 10, a.backend)
        elif what == "rollout_memory":
            r = rollout_memory(mem_n, 60, arg, a.backend)
        elif what.startswith("camera_"):
            r = camera(what, 8000, arg)
        else:
            r = peer(arg)
            if r is None:
                tqdm.write("peer: taichi not installed (pip install -r bench/requirements-peers.txt); skipped")
                continue
        r.setdefault("peak_mem_bytes", _vm("VmHWM"))
        r.update(commit=_commit(), date=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                 threads=torch.get_num_threads(), backend=a.backend)
        records.append(r)
    _print_table(records)
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(records, indent=1))
    if a.history and a.history.parent.is_dir():
        with a.history.open("a") as f:
            for r in records:
                f.write(json.dumps(r) + "\n")
    return records


def _print_table(records):
    ours = {r["particles"]: r["particle_steps_per_s"] for r in records if r["what"] == "forward"}
    print(f"\n{'what':<18}{'particles':>10}{'p-steps/s':>14}{'peak MB':>10}  notes")
    for r in records:
        note = ""
        if r["what"] == "forward":
            note = f"{r['neighbors_per_particle']:.1f} neighbours/particle"
        elif r["what"] == "forward_backward":
            note = f"fwd+bwd / fwd = {r['ratio_to_forward']:.2f}x"
        elif r["what"] == "rollout_memory":
            note = f"60 steps, checkpointed={r['checkpointed']}, rollout {r['rollout_bytes'] / 2**20:.0f} MB"
        elif r["what"] == "peer":
            mine = min(ours, key=lambda k: abs(k - r["particles"])) if ours else None
            if mine:
                note = f"{r.get('peer', 'peer')}; ours/peer = {ours[mine] / r['particle_steps_per_s']:.2f}"
        elif r["what"].startswith("camera_"):
            extra = {"camera_mask": f", coverage {r.get('coverage_ms', 0):.2f} ms",
                     "camera_splat": f" fwd+bwd, fwd {r.get('forward_ms', 0):.2f} ms"}
            extra = extra.get(r["what"], "")
            note = f"{r['ms']:.2f} ms{extra} on {r['device']}, {r['width']}x{r['height']}"
        print(f"{r['what']:<18}{r['particles']:>10}{r.get('particle_steps_per_s', 0):>14,.0f}"
              f"{r['peak_mem_bytes'] / 2**20:>10.0f}  {note}")


if __name__ == "__main__":
    main()
