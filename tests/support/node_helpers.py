"""Shared by the camera node tests: a local MJPEG server and `intspace serve` without the twin."""

from __future__ import annotations

import http.server
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx


class MjpegStream:
    """An MJPEG server cycling through `frames` at `fps`, each part stamped with X-Timestamp."""

    def __init__(self, frames: list[bytes], fps: float = 8.0) -> None:
        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:
                pass

            def do_GET(self) -> None:
                self.send_response(200)
                self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=b")
                self.end_headers()
                k = 0
                while True:
                    body = frames[k % len(frames)]
                    head = (
                        f"--b\r\nContent-Type: image/jpeg\r\nContent-Length: {len(body)}\r\n"
                        f"X-Timestamp: {time.time():.6f}\r\n\r\n"
                    )
                    try:
                        self.wfile.write(head.encode() + body + b"\r\n")
                        self.wfile.flush()
                    except (BrokenPipeError, ConnectionResetError):
                        return
                    k += 1
                    time.sleep(1.0 / fps)

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/stream.mjpg"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def node_env() -> dict[str, str]:
    """Return this process's environment without any INTSPACE_ setting."""
    return {k: v for k, v in os.environ.items() if not k.startswith("INTSPACE_")}


def serve_without_twin(repo_root: Path, data_dir: Path, token: str) -> tuple[subprocess.Popen, str]:
    """Start `intspace serve` without the twin, `token` its admin token; return the process
    and its API URL once healthy."""
    port = free_port()
    env = node_env()
    env.update(
        INTSPACE_DATA_DIR=str(data_dir),
        INTSPACE_SIMULATION="false",
        INTSPACE_VISER_ENABLED="false",
        INTSPACE_ADMIN_TOKEN=token,
    )
    process = subprocess.Popen(
        [sys.executable, "-m", "server.cli", "serve", "--port", str(port)],
        cwd=repo_root,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    api = f"http://127.0.0.1:{port}/api/v1"
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        assert process.poll() is None, "intspace serve exited"
        try:
            if (
                httpx.get(
                    f"{api}/health", headers={"Authorization": f"Bearer {token}"}, timeout=2
                ).status_code
                == 200
            ):
                return process, api
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    process.kill()
    raise AssertionError("intspace serve did not answer within 90 s")
