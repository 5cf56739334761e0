"""Observation ingest: detections per second through POST /api/v1/observations on one worker.

Starts `intspace serve` (one uvicorn worker, scene and twin off, temporary SQLite database) on a
free loopback port, registers 4 ceiling cameras looking at a 4 m x 3 m floor, and sends batches
of `--batch` detections (targets seen by every camera, exact projections plus 0.5 px noise) from
`--clients` concurrent clients for `--duration` seconds. It reports detections per second
accepted (200 responses), the batch latency p50/p99, and the localisation error of the returned
positions against the truth. The spec's target: >= 5,000 detections per second.

    python -m bench.bench_ingest [--batch 2000] [--clients 2] [--duration 10]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

from bench.bench_api import HEADERS, TOKEN
from core.localization import NetworkCamera
from tests.support.cameras import register_cameras
from tests.support.room import ceiling_cameras
from tests.support.service import running_service

TARGET_PER_S = 5000.0
POSITIONS = ([0.0, 0.0, 2.8], [4.0, 0.0, 2.8], [4.0, 3.0, 2.8], [0.0, 3.0, 2.8])


def register(base: str) -> tuple[list[int], list[NetworkCamera]]:
    """Create the 4 cameras in the registry (no distortion known); return their ids and
    models."""
    cams = ceiling_cameras(POSITIONS, dist=None)
    with httpx.Client() as client:
        ids = register_cameras(
            client, HEADERS, cams, prefix="ingest-", url=f"{base}/cameras", with_dist=False
        )
    return ids, cams


def make_batch(
    ids: list[int], cams: list[NetworkCamera], size: int, rng: np.random.Generator
) -> tuple[bytes, np.ndarray]:
    """Return a JSON body of `size` detections (size / 4 targets, each seen by the 4 cameras)
    and the targets' true floor positions."""
    n = size // len(cams)
    truth = rng.uniform([0.5, 0.5], [3.5, 2.5], (n, 2))
    X = np.column_stack([truth, np.zeros(n)])
    observations = []
    for cid, cam in zip(ids, cams, strict=True):
        px = cam.project(X) + 0.5 * rng.standard_normal((n, 2))
        observations += [
            {"camera_id": cid, "t": 1.0, "pixel": p, "sigma_px": 0.5, "target": f"p{j}"}
            for j, p in enumerate(px.tolist())
        ]
    return json.dumps({"observations": observations}).encode(), truth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=2000, help="detections per request")
    parser.add_argument("--clients", type=int, default=2, help="concurrent clients")
    parser.add_argument("--duration", type=float, default=10.0, help="seconds of load")
    args = parser.parse_args()

    with (
        tempfile.TemporaryDirectory() as tmp,
        running_service(
            Path(tmp),
            token=TOKEN,
            env={"INTSPACE_VISER_ENABLED": "false"},
            args=("--log-level", "warning"),
        ) as service,
    ):
        base = service.api
        ids, cams = register(base)
        rng = np.random.default_rng(0)
        batches = [make_batch(ids, cams, args.batch, rng) for _ in range(8)]
        latencies: list[float] = []
        errors: list[float] = []
        failures = [0]
        lock = threading.Lock()
        stop = time.monotonic() + args.duration

        def client_loop(k: int) -> None:
            headers = {**HEADERS, "Content-Type": "application/json"}
            with httpx.Client(headers=headers, timeout=60) as client:
                i = k
                while time.monotonic() < stop:
                    body, truth = batches[i % len(batches)]
                    t0 = time.perf_counter()
                    response = client.post(f"{base}/observations", content=body)
                    dt = time.perf_counter() - t0
                    with lock:
                        if response.status_code != 200:
                            failures[0] += 1
                        else:
                            latencies.append(dt)
                            if i < len(batches):
                                xy = np.array([p["xy"] for p in response.json()["positions"]])
                                errors.extend(np.linalg.norm(xy - truth, axis=1).tolist())
                    i += args.clients

        # Warm-up: the first request builds the camera cache.
        httpx.post(f"{base}/observations", content=batches[0][0], headers=HEADERS, timeout=60)
        t_start = time.monotonic()
        threads = [threading.Thread(target=client_loop, args=(k,)) for k in range(args.clients)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        elapsed = time.monotonic() - t_start

    per_batch = (args.batch // len(cams)) * len(cams)
    rate = len(latencies) * per_batch / elapsed
    lat = np.array(latencies) * 1e3
    print(f"batch {per_batch} detections, {args.clients} clients, {elapsed:.1f} s, one worker")
    print(f"accepted: {len(latencies)} batches, {rate:,.0f} detections/s, failures {failures[0]}")
    p50, p99 = np.percentile(lat, [50, 99])
    print(f"batch latency: p50 {p50:.1f} ms, p99 {p99:.1f} ms")
    rms = float(np.sqrt(np.mean(np.square(errors)))) if errors else float("nan")
    print(f"position RMS error vs truth (0.5 px noise, 4 cameras): {rms * 1000:.2f} mm")
    verdict = "meets" if rate >= TARGET_PER_S and failures[0] == 0 else "MISSES"
    print(f"{verdict} the target of {TARGET_PER_S:,.0f} detections/s")


if __name__ == "__main__":
    main()
