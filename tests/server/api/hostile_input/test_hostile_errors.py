"""Errors that keep the connection and say what happened: API paths answered by the API, not the
static files, and an unhandled error as a 500 with a request id."""

from __future__ import annotations

import http.client
import json
import threading
import time
from pathlib import Path

import pytest

from tests.support.hostile_requests import TOKEN
from tests.support.ports import free_port


@pytest.mark.parametrize(
    ("method", "path", "status", "allow"),
    [
        ("GET", "/api/v1/observations", 405, "POST"),
        ("GET", "/api/v1/twin/pause", 405, "POST"),
        ("DELETE", "/api/v1/spaces", 405, "GET, POST"),
        ("POST", "/api/v1/no-such-resource", 404, None),
        ("GET", "/api/v1/spaces/1/no-such-thing", 404, None),
    ],
)
def test_api_paths_are_answered_by_the_api_not_the_static_files(case, method, path, status, allow):
    got, headers, problem, _, _ = case.send(method, path)
    assert got == status, problem
    assert headers.get("allow") == allow
    assert problem["status"] == status and path in problem["detail"]
    case.next_request_answered()


def test_an_unhandled_error_is_a_500_with_a_request_id_and_keeps_the_connection(
    tmp_path: Path, sqlite_template: Path, caplog: pytest.LogCaptureFixture
):
    import shutil

    import uvicorn
    from fastapi.routing import APIRoute

    from server.app import create_app
    from server.settings import Settings

    shutil.copyfile(sqlite_template, tmp_path / "intspace.sqlite3")
    app = create_app(
        Settings(_env_file=None, data_dir=tmp_path, admin_token=TOKEN, viser_enabled=False)
    )

    def broken() -> None:
        raise RuntimeError("a bug")

    # First, ahead of the API's own fallback for unknown paths.
    app.router.routes.insert(0, APIRoute("/api/v1/broken", broken, methods=["GET"]))
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 30
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        with caplog.at_level("ERROR", logger="server.api.errors"):
            conn.request("GET", "/api/v1/broken")
            response = conn.getresponse()
            problem = json.loads(response.read())
        assert response.status == 500
        assert response.getheader("content-type") == "application/problem+json"
        request_id = problem["request_id"]
        assert response.getheader("x-request-id") == request_id and request_id in problem["detail"]
        # The traceback, once, under that id.
        logged = [r for r in caplog.records if request_id in r.getMessage()]
        assert len(logged) == 1 and logged[0].exc_info is not None
        # Before: uvicorn dropped the connection after the answer.
        sock = conn.sock
        conn.request("GET", "/api/v1/health")
        assert conn.getresponse().status == 200
        assert conn.sock is sock
        conn.close()
    finally:
        server.should_exit = True
        thread.join(timeout=30)
