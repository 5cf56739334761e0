"""The services of the end-to-end bench: `intspace serve` with the twin (started by
tests/support/service.py, detection `internal` or `external`) with a client of its API, and one
`intspace node` reading every twin camera's MJPEG stream, stopped with Ctrl-C and its log read
for what it posted."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx

from tests.support.service import REPO_ROOT, clean_env, start_service

TOKEN = "end-to-end-admin-token"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}


class TwinService:
    """`intspace serve` with the twin (tests/support/service.py), detection `internal` or
    `external`, and a client of its API."""

    def __init__(
        self, data_dir: Path, detection: str, seed: int, tracker_latency_s: float | None = None
    ) -> None:
        env = {
            "INTSPACE_SIMULATION": "true",
            "INTSPACE_TWIN_DETECTION": detection,
            "INTSPACE_TWIN_SEED": str(seed),
            "INTSPACE_VISER_ENABLED": "false",
        }
        if tracker_latency_s is not None:
            env["INTSPACE_TRACKER_LATENCY_S"] = str(tracker_latency_s)
        self.served = start_service(data_dir, token=TOKEN, env=env, wait=False)
        self.api = self.served.api
        self.http = httpx.Client(base_url=self.api, headers=HEADERS, timeout=10)

    def wait_healthy(self) -> None:
        self.served.wait_healthy()

    def get(self, path: str, **params: Any) -> Any:
        response = self.http.get(path, params=params)
        if response.status_code != 200:
            raise RuntimeError(f"GET {path} answered {response.status_code}: {response.text}")
        return response.json()

    def stop(self) -> None:
        self.http.close()
        self.served.stop()


def start_node(service: TwinService, folder: Path) -> subprocess.Popen:
    """Start one `intspace node` reading every twin camera's MJPEG stream, with an ingest token
    bound to those cameras and a YAML file naming the space (as a user would set it up)."""
    twin = service.get("/twin")
    ids: dict[str, int] = twin["cameras"]
    space_id = service.get(f"/cameras/{next(iter(ids.values()))}")["space_id"]
    created = service.http.post(
        "/tokens", json={"name": "node", "scopes": ["ingest"], "camera_ids": list(ids.values())}
    )
    if created.status_code != 201:
        raise RuntimeError(f"POST /tokens answered {created.status_code}: {created.text}")
    config = folder / "node.yaml"
    config.write_text(
        f"space: {space_id}\ncameras:\n"
        + "".join(
            f"  - name: {name}\n    source: {service.api}/cameras/{camera_id}/stream.mjpg\n"
            for name, camera_id in ids.items()
        ),
        encoding="utf-8",
    )
    env = clean_env()
    env["INTSPACE_TOKEN"] = created.json()["token"]
    with (folder / "node.log").open("w") as out:
        return subprocess.Popen(
            [
                sys.executable,
                "-m",
                "server.cli",
                "node",
                "--config",
                str(config),
                "--api",
                service.api,
            ],
            cwd=REPO_ROOT,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=out,
        )


def stop_node(node: subprocess.Popen) -> None:
    if node.poll() is None:
        node.send_signal(signal.SIGINT)  # the node posts what it holds and says what it did
        try:
            node.wait(15)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()


def node_counts(log: str) -> tuple[int | None, int | None]:
    """Return (detections posted, camera frames too late to be tracked) from a node's log."""
    match = re.search(
        r"posted (\d+) detection\(s\) and \d+ empty frame\(s\); (\d+) camera frame\(s\) "
        r"came too late",
        log,
    )
    return (int(match[1]), int(match[2])) if match else (None, None)
