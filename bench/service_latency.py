"""End-to-end latency of the service and how many sessions one server sustains.

    .venv/bin/python bench/service_latency.py [--particles 2000 4000 8000] [--seconds 10]
                                              [--sessions 1 2 3 4] [--threads 2]

Starts a real ``liquidtwin serve`` process on 127.0.0.1 and drives it through the real
client library at 30 Hz: per frame a 640×480 liquid mask, then the poses of a bowl rocking
±8° (so the liquid moves) and of the camera. Latency = publishing a frame's poses →
receiving that frame's particles, both in this process. A session *keeps up* when it
answers ≥ 95 % of the frames, its median latency is under one frame period (33 ms) and
its simulation clock never had to jump (``Metrics.sim_lag_s`` = 0).

Records (``what`` = "service_latency" per particle count, "service_sessions" per session
count) are printed and appended to bench/history.jsonl. Server peak memory is its VmHWM.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from liquidtwin_client import Client
from liquidtwin_proto import liquidtwin_pb2 as pb

ROOT = Path(__file__).resolve().parents[1]
HZ = 30.0
ML_PER_PARTICLE = 0.105  # fill volume per wanted particle; the fill settles to its own count
                         # (2000 -> 2.6k, 8000 -> 8.2k in the fruit bowl): records give the served count
W, H = 640, 480


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _camera() -> tuple[np.ndarray, np.ndarray]:
    """K (3, 3) and the camera → world pose (7,) of a camera 45 cm from the bowl."""
    from liquidtwin.camera import Camera
    cam = Camera.look_at((0.0, 0.35, 0.30), (0.0, 0.03, 0.0), width=W, height=H, fov_y_deg=45.0)
    return cam.K.double().numpy(), cam.pose.double().numpy()


def _spec(particles: int, dt: float, iterations: int) -> pb.SessionSpec:
    spec = pb.SessionSpec(device="cpu")
    scene = spec.scene
    scene.name = f"bench_bowl_{particles}"
    scene.simulation.h, scene.simulation.dt, scene.simulation.iterations = 0.011, dt, iterations
    scene.simulation.spacing = 0.55 * 0.011
    bowl = scene.objects.add(name="bowl", model="fruit_bowl", container=True)
    bowl.initial_pose.extend([0, 0, 0, 0, 0, 0, 1])
    scene.fills.add(container="bowl", volume_ml=particles * ML_PER_PARTICLE)
    scene.cameras.append("cam")
    K, pose = _camera()
    spec.cameras.add(name="cam", width=W, height=H, k=K.ravel().tolist(), d=[0.0] * 5,
                     pose=pose.tolist())
    return spec


def _mask(K: np.ndarray, cam_pose: np.ndarray) -> np.ndarray:
    """An elliptical liquid blob where the bowl's liquid surface projects."""
    from liquidtwin.camera import Camera
    import torch
    cam = Camera.from_calibration(K, np.zeros(5), W, H, cam_pose)
    ring = np.array([[0.07 * math.cos(a), 0.03, 0.07 * math.sin(a)]
                     for a in np.linspace(0, 2 * math.pi, 64, endpoint=False)])
    uv, _ = cam.project(torch.as_tensor(ring, dtype=torch.float64))
    mask = np.zeros((H, W), np.uint8)
    cv2.fillPoly(mask, [uv.numpy().round().astype(np.int32)], 1)
    return mask.astype(bool)


def _bowl_pose(t: float) -> list[float]:
    a = math.radians(8.0) * math.sin(2 * math.pi * 0.5 * t)
    return [0.0, 0.0, 0.0, math.sin(a / 2), 0.0, 0.0, math.cos(a / 2)]


class _Run:
    """One session streamed at 30 Hz; latency per answered frame."""

    def __init__(self, client: Client, spec: pb.SessionSpec, name: str):
        self.session = client.create_session(spec, session_id=name, timeout=600.0)
        self.sent: dict[int, int] = {}
        self.latency_ms: list[float] = []
        self.sim_lag = 0.0
        self.particles = 0
        self.stale = 0
        self.steps = 0
        self._lock = threading.Lock()
        self.session.on("particles", self._particles)
        self.session.on("metrics", self._metrics)

    def _particles(self, out) -> None:
        with self._lock:
            t0 = self.sent.pop(out.header.stamp_ns, None)
        if t0 is not None:
            self.latency_ms.append((out.received_ns - t0) * 1e-6)

    def _metrics(self, out) -> None:
        m = out.message
        self.sim_lag = max(self.sim_lag, m.sim_lag_s)
        self.particles, self.stale = m.particles, m.dropped_stale
        self.steps += m.steps

    def frame(self, stamp_ns: int, t: float, mask, cam_pose) -> None:
        self.session.publish_mask("cam", mask, stamp_ns=stamp_ns)
        with self._lock:
            self.sent[stamp_ns] = time.time_ns()
        self.session.publish_poses({"bowl": _bowl_pose(t), "cam": cam_pose}, stamp_ns=stamp_ns)


def _drive(runs: list[_Run], seconds: float, mask, cam_pose) -> None:
    n = int(seconds * HZ)
    start, t0 = time.perf_counter(), time.time_ns()
    for i in range(n):
        wait = start + i / HZ - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        for r in runs:
            r.frame(t0 + int(i * 1e9 / HZ), i / HZ, mask, cam_pose)
    time.sleep(1.0)  # let the last answers arrive


def _summary(run: _Run, frames: int) -> dict:
    lat = np.asarray(run.latency_ms) if run.latency_ms else np.asarray([math.inf])
    answered = len(run.latency_ms) / frames
    return {"particles": run.particles, "frames": frames, "answered": round(answered, 3),
            "p50_ms": round(float(np.percentile(lat, 50)), 1),
            "p99_ms": round(float(np.percentile(lat, 99)), 1),
            "sim_lag_s": round(run.sim_lag, 3), "dropped_stale": run.stale,
            "keeps_up": bool(answered >= 0.95 and np.percentile(lat, 50) < 1e3 / HZ
                             and run.sim_lag == 0.0)}


def _server_peak(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return 0


def _commit() -> str:
    return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          cwd=ROOT).stdout.strip() or "unknown"


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--particles", type=int, nargs="+", default=[2000, 4000, 8000])
    p.add_argument("--sessions", type=int, nargs="*", default=[1, 2, 3, 4],
                   help="concurrent 2k-particle sessions to try (empty: skip)")
    p.add_argument("--seconds", type=float, default=10.0, help="streamed time per run")
    p.add_argument("--dt", type=float, default=1 / 60, help="simulation step, s (default 1/60: two steps per 30 Hz frame)")
    p.add_argument("--iterations", type=int, default=4)
    p.add_argument("--threads", type=int, default=2, help="server torch threads")
    p.add_argument("--history", type=Path, default=ROOT / "bench" / "history.jsonl")
    a = p.parse_args(argv)
    port = _free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    K, cam_pose = _camera()
    mask = _mask(K, cam_pose)
    records = []
    with tempfile.TemporaryDirectory() as state:
        server = subprocess.Popen(
            [str(Path(sys.executable).parent / "liquidtwin"), "serve", "--listen", endpoint,
             "--state-dir", state, "--threads", str(a.threads), "--max-sessions", "64"],
            stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            if "ready" not in server.stdout.readline():
                raise SystemExit("liquidtwin serve did not start")
            with Client(connect=endpoint) as client:
                base = {"dt": a.dt, "iterations": a.iterations, "hz": HZ, "threads": a.threads,
                        "seconds": a.seconds}
                for n in a.particles:
                    run = _Run(client, _spec(n, a.dt, a.iterations), f"lat{n}")
                    _drive([run], a.seconds, mask, cam_pose)
                    rec = {"what": "service_latency", **base, **_summary(run, int(a.seconds * HZ))}
                    # simulated particle-steps per wall second (real time needs particles / dt)
                    rec["particle_steps_per_s"] = round(rec["particles"] * run.steps / a.seconds)
                    rec["realtime_factor"] = round(run.steps * a.dt / a.seconds, 3)
                    run.session.close()
                    records.append(rec)
                    print(json.dumps(rec), flush=True)
                for k in a.sessions:
                    runs = [_Run(client, _spec(2000, a.dt, a.iterations), f"s{k}_{i}") for i in range(k)]
                    _drive(runs, a.seconds, mask, cam_pose)
                    each = [_summary(r, int(a.seconds * HZ)) for r in runs]
                    rec = {"what": "service_sessions", **base, "sessions": k,
                           "particles": each[0]["particles"],
                           "keeps_up": all(e["keeps_up"] for e in each),
                           "p50_ms": max(e["p50_ms"] for e in each),
                           "p99_ms": max(e["p99_ms"] for e in each),
                           "answered": min(e["answered"] for e in each)}
                    for r in runs:
                        r.session.close()
                    records.append(rec)
                    print(json.dumps(rec), flush=True)
                    if not rec["keeps_up"]:
                        break
            peak = _server_peak(server.pid)
        finally:
            server.terminate()
            server.wait(30)
    date = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    for r in records:
        r.update(peak_mem_bytes=peak, commit=_commit(), date=date)
    if a.history.parent.is_dir():
        with a.history.open("a") as f:
            f.writelines(json.dumps(r) + "\n" for r in records)
    return records


if __name__ == "__main__":
    main()
