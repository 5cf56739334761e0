"""Soak: 50 clients across two `intspace serve` processes on one PostgreSQL database.

Creates a fresh database on the PostgreSQL server of `--postgres-url` (default:
INTSPACE_TEST_POSTGRES_URL), migrates it, starts two `intspace serve` processes on free loopback
ports (no twin, no 3D scene), registers four ceiling cameras, and for `--minutes` runs:

* 4 camera-node clients, one per camera, each capturing its camera's frame (unlabelled
  detections of three walkers, 0.5 px noise, 5 % missed) 10 times a second with its own phase
  and posting what it has queued as `intspace node` does (one request at a time, everything
  queued since the last), to the two processes alternately (camera k to process k % 2); their
  line counts frames, each from its capture to the 2xx that stored it;
* the other clients (46 of 50) reading at `--rate` requests per second each, open loop, half on
  each process: a camera, the camera list, the live targets, a target's track, the spaces;
* one targets WebSocket per process, read by a process of its own (as a dashboard is, not by
  the load generator's busy event loop), counting its messages and how old the newest position
  in each is (its capture time to the message's arrival: capture -> post -> the owner's
  tracker -> fan-out -> this process's stream).

A request's latency is measured from its scheduled time (no coordinated omission; see
bench_api.py). Prints p50 and p99 per endpoint and the errors (non-2xx answers, transport
errors); the exit code is 1 when there was any error. Spec 06 asks for zero errors in a
5-minute soak and p99 < 50 ms for registry reads at 50 clients. The load generator runs on the
same machine and costs CPU per request too.

    python -m bench.bench_soak_two_processes [--minutes 5] [--clients 50] [--rate 2]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import subprocess
import sys
import tempfile
import time
import uuid
from collections import defaultdict
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

from core.localization import NetworkCamera
from tests.support.cameras import register_cameras
from tests.support.room import CAPTURE_DELAY_S, HEIGHT, SIGMA_PX, ceiling_cameras
from tests.support.service import WITHOUT_TWIN, Service, clean_env, start_service

REPO_ROOT = Path(__file__).resolve().parents[1]
TOKEN = "bench-soak-admin-token"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}
NODE_HZ = 10.0


def make_database(server_url: str) -> str:
    """Create an empty database on the server of `server_url`; return its URL."""
    server = make_url(server_url)
    name = f"intspace_soak_{uuid.uuid4().hex[:10]}"
    admin = create_engine(server, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(text(f'CREATE DATABASE "{name}"'))
    admin.dispose()
    return server.set(database=name).render_as_string(hide_password=False)


def drop_database(server_url: str, url: str) -> None:
    admin = create_engine(make_url(server_url), isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        name = make_url(url).database
        connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    admin.dispose()


def start_servers(database_url: str, data_dir: Path, n: int = 2) -> list[Service]:
    """Migrate once, then start n `intspace serve` processes side by side (neither runs the
    twin nor the 3D scene); return them once all answer."""
    settings = {"INTSPACE_DATABASE_URL": database_url}
    subprocess.run(
        [sys.executable, "-m", "server.cli", "db", "upgrade"],
        cwd=REPO_ROOT,
        env={**clean_env(), **settings},
        check=True,
        stdout=subprocess.DEVNULL,
    )
    services = [
        start_service(
            data_dir,
            token=TOKEN,
            env={**settings, **WITHOUT_TWIN},
            args=("--log-level", "warning"),
            log_path=data_dir / f"serve{i}.log",
            wait=False,
        )
        for i in range(n)
    ]
    try:
        for service in services:
            service.wait_healthy()
    except BaseException:
        for service in services:
            if service.process.poll() is None:
                service.kill()
        raise
    return services


def tracker_owners(database_url: str, pids: list[int]) -> list[int]:
    """Return the indices (in `pids`) of the processes that hold a space's tracker lock
    (server.services.ownership names its lock connection after its process id)."""
    from server.services.ownership import APPLICATION_NAME, NAMESPACE

    query = text(
        "SELECT a.application_name FROM pg_locks l JOIN pg_stat_activity a USING (pid) "
        "WHERE l.locktype = 'advisory' AND l.classid = :ns AND l.granted "
        "AND a.datname = current_database()"
    )
    engine = create_engine(make_url(database_url))
    with engine.connect() as connection:
        names = list(connection.execute(query, {"ns": NAMESPACE}).scalars())
    engine.dispose()
    return [i for i, pid in enumerate(pids) if f"{APPLICATION_NAME}:{pid}" in names]


def make_cameras() -> list[NetworkCamera]:
    """Four ceiling cameras at the corners of a 4 m x 3 m room, looking at its middle."""
    return ceiling_cameras(([0.0, 0.0, 2.8], [4.0, 0.0, 2.8], [4.0, 3.0, 2.8], [0.0, 3.0, 2.8]))


def walkers(t: float) -> np.ndarray:
    """Three people walking circles about the room's middle (3, 3): x, y, height."""
    radius = np.array([0.5, 0.9, 1.2])
    phase = np.array([0.0, 2.1, 4.2])
    a = phase + np.array([0.6, -0.45, 0.3]) * t
    return np.column_stack(
        [2.0 + radius * np.cos(a), 1.5 + 0.8 * radius * np.sin(a), np.full(3, HEIGHT)]
    )


def register(base: str, cameras: list[NetworkCamera]) -> list[int]:
    with httpx.Client(timeout=10) as client:
        return register_cameras(client, HEADERS, cameras, prefix="soak-", url=f"{base}/cameras")


class Results:
    """Latencies (s) and errors per (endpoint, process)."""

    def __init__(self) -> None:
        self.latency: dict[str, list[float]] = defaultdict(list)
        self.errors: dict[str, int] = defaultdict(int)
        self.error_samples: list[str] = []

    def add(self, name: str, seconds: float, ok: bool, detail: str = "") -> None:
        self.latency[name].append(seconds)
        if not ok:
            self.errors[name] += 1
            if len(self.error_samples) < 10:
                self.error_samples.append(f"{name}: {detail}")


async def node_loop(
    client: httpx.AsyncClient,
    base: str,
    k: int,
    camera_id: int,
    camera: NetworkCamera,
    t0: float,
    stop_at: float,
    results: Results,
    name: str,
) -> None:
    """One camera node, as `intspace node` works: it captures a frame of camera k every
    1 / NODE_HZ s with its own phase and queues its detections; a poster sends everything
    queued in one request as soon as the previous one has returned. Each frame's latency runs
    from its capture to the 2xx that stored it, so a service that cannot keep up shows as a
    growing latency, and a node that waits on a slow answer still keeps its frame rate."""
    rng = np.random.default_rng(100 + k)
    period = 1.0 / NODE_HZ
    queue: list[tuple[float, list[dict]]] = []  # (capture perf time, observations)
    ready = asyncio.Event()

    async def capture() -> None:
        scheduled = time.perf_counter() + period * (k + 0.5) / 4
        while time.monotonic() < stop_at:
            delay = scheduled - time.perf_counter()
            if delay > 0:
                await asyncio.sleep(delay)
            t = time.time() - CAPTURE_DELAY_S
            X = walkers(t - t0)
            seen = camera.in_view(X) & (rng.random(3) > 0.05)
            px = camera.project(X[seen]) + rng.normal(0.0, SIGMA_PX, (int(seen.sum()), 2))
            observations = [
                {
                    "camera_id": camera_id,
                    "t": t,
                    "pixel": p.tolist(),
                    "sigma_px": SIGMA_PX,
                    "kind": "person",
                    "height": HEIGHT,
                }
                for p in px
            ]
            if observations:
                queue.append((scheduled - CAPTURE_DELAY_S, observations))
                ready.set()
            scheduled += period

    async def post() -> None:
        while time.monotonic() < stop_at or queue:
            if not queue:
                ready.clear()
                try:
                    await asyncio.wait_for(ready.wait(), timeout=0.5)
                except TimeoutError:
                    continue
                continue
            batch = queue[:]
            del queue[:]
            body = {"observations": [o for _, obs in batch for o in obs]}
            try:
                response = await client.post(f"{base}/observations", json=body)
                ok, detail = response.status_code == 200, f"{response.status_code}"
            except httpx.HTTPError as exc:
                ok, detail = False, repr(exc)
            done = time.perf_counter()
            for captured, _ in batch:
                results.add(name, done - captured, ok, detail)

    await asyncio.gather(capture(), post())


async def reader_loop(
    client: httpx.AsyncClient,
    base: str,
    proc: int,
    ids: list[int],
    rate: float,
    stop_at: float,
    results: Results,
    seed: int,
) -> None:
    """Reads at `rate` per second: a camera, the camera list, the targets, a track, spaces."""
    rng = np.random.default_rng(seed)
    period = 1.0 / rate
    scheduled = time.perf_counter() + period * rng.random()
    target_ids: list[int] = []
    while time.monotonic() < stop_at:
        delay = scheduled - time.perf_counter()
        if delay > 0:
            await asyncio.sleep(delay)
        r = rng.random()
        if r < 0.4:
            name, url = "GET /cameras/{id}", f"{base}/cameras/{ids[int(rng.integers(len(ids)))]}"
        elif r < 0.55:
            name, url = "GET /cameras", f"{base}/cameras?limit=20"
        elif r < 0.8:
            name, url = "GET /targets", f"{base}/targets"
        elif r < 0.9 and target_ids:
            tid = target_ids[int(rng.integers(len(target_ids)))]
            name, url = "GET /targets/{id}/track", f"{base}/targets/{tid}/track?limit=200"
        else:
            name, url = "GET /spaces", f"{base}/spaces"
        start = scheduled
        try:
            response = await client.get(url)
            ok, detail = response.status_code == 200, f"{response.status_code} {url}"
            if ok and name == "GET /targets":
                target_ids = [t["id"] for t in response.json()["items"]]
        except httpx.HTTPError as exc:
            ok, detail = False, repr(exc)
        results.add(f"{name} [p{proc}]", time.perf_counter() - start, ok, detail)
        scheduled += period


async def stream_loop(base: str, stop_at: float, ages: list[float], counts: list[int]) -> None:
    """Read a targets WebSocket: count messages, and how old each one's newest position is."""
    from websockets.asyncio.client import connect

    url = base.replace("http://", "ws://") + "/ws/targets"
    async with connect(url, additional_headers=HEADERS) as ws:
        while time.monotonic() < stop_at:
            try:
                raw = await asyncio.wait_for(ws.recv(), timeout=1.0)
            except TimeoutError:
                continue
            message = json.loads(raw)
            counts[0] += 1
            if message.get("t") is not None:
                ages.append(time.time() - message["t"])


def _streams(bases: list[str], stop_wall: float, out: Any) -> None:
    """Read the targets WebSocket of every process until the Unix time `stop_wall` (the
    load's end); put (ages, counts) in `out` (a multiprocessing queue). Run in a process of
    its own, as a dashboard is: in the load generator's event loop, busy with 50 clients, the
    stream would be read late and its messages would age in the socket buffers, which is not
    the service's delay."""

    async def run() -> tuple[list[list[float]], list[int]]:
        stop_at = time.monotonic() + (stop_wall - time.time())
        ages: list[list[float]] = [[] for _ in bases]
        counts = [[0] for _ in bases]
        await asyncio.gather(
            *(stream_loop(b, stop_at, ages[i], counts[i]) for i, b in enumerate(bases))
        )
        return ages, [c[0] for c in counts]

    out.put(asyncio.run(run()))


async def soak(
    bases: list[str], ids: list[int], cameras: list[NetworkCamera], args: argparse.Namespace
) -> tuple[Results, list[list[float]], list[int], float]:
    results = Results()
    n_nodes = len(cameras)
    readers = args.clients - n_nodes
    pool = [httpx.AsyncClient(headers=HEADERS, timeout=10) for _ in range(args.clients)]
    try:
        await asyncio.gather(*(c.get(f"{bases[i % 2]}/health") for i, c in enumerate(pool)))
        t0 = time.time()
        stop_at = time.monotonic() + 60.0 * args.minutes
        context = multiprocessing.get_context("spawn")
        streamed = context.Queue()
        stop_wall = time.time() + (stop_at - time.monotonic())
        streams = context.Process(target=_streams, args=(bases, stop_wall, streamed))
        streams.start()
        start = time.perf_counter()
        tasks = [
            node_loop(
                pool[k],
                bases[k % 2],
                k,
                ids[k],
                cameras[k],
                t0,
                stop_at,
                results,
                f"POST /observations [p{k % 2}]",
            )
            for k in range(n_nodes)
        ]
        tasks += [
            reader_loop(
                pool[n_nodes + j],
                bases[j % 2],
                j % 2,
                ids,
                args.rate,
                stop_at,
                results,
                seed=j,
            )
            for j in range(readers)
        ]
        await asyncio.gather(*tasks)
        wall = time.perf_counter() - start
        ages, counts = await asyncio.to_thread(streamed.get, True, 60.0)
        await asyncio.to_thread(streams.join, 10.0)
    finally:
        await asyncio.gather(*(c.aclose() for c in pool))
    return results, ages, counts, wall


def main(argv: list[str] | None = None) -> int:
    """Run the soak; return 0 when no request failed."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=5.0)
    parser.add_argument("--clients", type=int, default=50, help="Camera nodes (4) + readers.")
    parser.add_argument("--rate", type=float, default=2.0, help="Reads per second per reader.")
    parser.add_argument(
        "--postgres-url",
        default=os.environ.get("INTSPACE_TEST_POSTGRES_URL"),
        help="A PostgreSQL server URL (SQLAlchemy); a fresh database is made on it.",
    )
    args = parser.parse_args(argv)
    if not args.postgres_url:
        parser.error("a PostgreSQL server is needed: --postgres-url or INTSPACE_TEST_POSTGRES_URL")
    if args.clients < 6:
        parser.error("--clients must be at least 6 (4 camera nodes and 2 readers)")
    database_url = make_database(args.postgres_url)
    servers: list[Service] = []
    try:
        with tempfile.TemporaryDirectory(prefix="intspace-soak-") as tmp:
            try:
                servers = start_servers(database_url, Path(tmp))
                bases = [s.api for s in servers]
                cameras = make_cameras()
                ids = register(bases[0], cameras)
                print(
                    f"soak: {args.minutes:g} min, {args.clients} clients (4 camera nodes at "
                    f"{NODE_HZ:g} Hz, {args.clients - 4} readers at {args.rate:g}/s), two "
                    "processes"
                )
                results, ages, counts, wall = asyncio.run(soak(bases, ids, cameras, args))
                alive = [s.process.poll() is None for s in servers]
                owners = tracker_owners(database_url, [s.process.pid for s in servers])
            finally:
                for server in servers:
                    server.stop()
    finally:
        drop_database(args.postgres_url, database_url)

    total_errors = sum(results.errors.values())
    width = max(len(n) for n in results.latency)
    print(f"{'endpoint':<{width}}  {'count':>7}  {'p50 ms':>7}  {'p99 ms':>7}  {'errors':>6}")
    for name in sorted(results.latency):
        lat = np.asarray(results.latency[name]) * 1e3
        print(
            f"{name:<{width}}  {lat.size:>7}  {np.percentile(lat, 50):>7.1f}  "
            f"{np.percentile(lat, 99):>7.1f}  {results.errors[name]:>6}"
        )
    reads = np.concatenate(
        [np.asarray(v) for n, v in results.latency.items() if n.startswith("GET")]
    )
    print(
        f"all reads: {reads.size} in {wall:.0f} s, p50 {np.percentile(reads, 50) * 1e3:.1f} ms, "
        f"p99 {np.percentile(reads, 99) * 1e3:.1f} ms"
    )
    for i, (a, c) in enumerate(zip(ages, counts, strict=True)):
        if a:
            arr = np.asarray(a) * 1e3
            print(
                f"targets WebSocket of p{i}: {c} messages, age of the newest position "
                f"(capture -> message) p50 {np.percentile(arr, 50):.0f} ms, "
                f"p99 {np.percentile(arr, 99):.0f} ms"
            )
        else:
            print(f"targets WebSocket of p{i}: {c} messages, none with a position")
    print(f"the space's tracker ran in: {', '.join(f'p{i}' for i in owners) or 'no process'}")
    print(f"errors: {total_errors}; processes alive at the end: {alive}")
    for sample in results.error_samples:
        print(f"  {sample}")
    return 0 if total_errors == 0 and all(alive) else 1


if __name__ == "__main__":
    sys.exit(main())
