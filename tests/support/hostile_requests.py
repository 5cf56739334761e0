"""Hostile requests against a real `intspace serve` process: each is sent on a keep-alive
connection (`Case`) that reports its answer and how much the server's peak RSS grew while
answering it (spec 06: memory bounded by the request, not by what it claims), and checks that
the next request on the same connection is answered; the space the requests aim at
(`make_home`)."""

from __future__ import annotations

import http.client
import json
from pathlib import Path
from typing import Any

from tests.support.service import Service

TOKEN = "hostile-input-admin-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
# The bound on the peak RSS growth of the server process per hostile request.
RSS_BOUND_MB = 150.0


def connect(service: Service) -> http.client.HTTPConnection:
    """Return a keep-alive connection to the service (requests may take long on a loaded box)."""
    return http.client.HTTPConnection("127.0.0.1", service.port, timeout=120)


def _status(service: Service, key: str) -> float:
    for line in Path(f"/proc/{service.process.pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return float(line.split()[1]) / 1024.0
    raise AssertionError(f"no {key} in /proc status")


def reset_peak(service: Service) -> float:
    """Reset the service's peak RSS to its current RSS; return that RSS (MB)."""
    Path(f"/proc/{service.process.pid}/clear_refs").write_text("5")
    return _status(service, "VmRSS")


def peak(service: Service) -> float:
    """Return the service's peak RSS (MB) since the last reset."""
    return _status(service, "VmHWM")


class Case:
    """One hostile request on a keep-alive connection, with the answer and the RSS growth."""

    def __init__(self, service: Service, conn: http.client.HTTPConnection) -> None:
        self.service = service
        self.conn = conn

    def send(
        self, method: str, path: str, body: bytes | dict | list | None = None, **headers: str
    ) -> tuple[int, dict[str, str], Any, float, int]:
        """Return (status, headers, JSON body or bytes, peak RSS growth MB, answer size)."""
        data = json.dumps(body).encode() if isinstance(body, dict | list) else body
        before = reset_peak(self.service)
        self.conn.request(method, path, body=data, headers={**AUTH, **headers})
        response = self.conn.getresponse()
        raw = response.read()
        growth = peak(self.service) - before
        # The figures, shown with `pytest -s`.
        print(f"{method} {path[:70]} -> {response.status}, peak RSS +{growth:.1f} MB")
        try:
            content: Any = json.loads(raw)
        except ValueError:
            content = raw
        headers = {k.lower(): v for k, v in response.getheaders()}
        return response.status, headers, content, growth, len(raw)

    def next_request_answered(self) -> None:
        """Assert that the same connection (the same socket) answers another request."""
        sock = self.conn.sock
        assert sock is not None, "the server closed the connection"
        self.conn.request("GET", "/api/v1/health")
        response = self.conn.getresponse()
        response.read()
        assert response.status == 200
        assert self.conn.sock is sock, "the client had to reconnect"


def json_answer(case: Case, method: str, path: str, body: Any = None) -> Any:
    """Return the JSON of a request that must succeed (status below 300)."""
    status, _, content, _, _ = case.send(method, path, body)
    assert status < 300, (status, content)
    return content


def make_home(service: Service) -> dict[str, Any]:
    """Create the space of `home`; return {space, cameras}."""
    conn = connect(service)
    try:
        c = Case(service, conn)
        space = json_answer(c, "POST", "/api/v1/spaces", {"name": "hostile"})
        json_answer(
            c,
            "POST",
            "/api/v1/rooms",
            {"space_id": space["id"], "name": "hall", "polygon": [[0, 0], [8, 0], [8, 6], [0, 6]]},
        )
        cameras = []
        for x, y in ((2.0, 1.5), (6.0, 1.5), (2.0, 4.5), (6.0, 4.5)):
            cameras.append(
                json_answer(
                    c,
                    "POST",
                    "/api/v1/cameras",
                    {
                        "name": f"ceiling-{x:g}-{y:g}",
                        "space_id": space["id"],
                        "width": 1280,
                        "height": 720,
                        "K": [[700, 0, 640], [0, 700, 360], [0, 0, 1]],
                        "dist": [0.01, -0.02, 0, 0, 0],
                        # Looking straight down from 2.6 m.
                        "T_world_camera": [
                            [1, 0, 0, x],
                            [0, -1, 0, y],
                            [0, 0, -1, 2.6],
                            [0, 0, 0, 1],
                        ],
                    },
                )
            )
        return {"space": space, "cameras": cameras}
    finally:
        conn.close()
