"""Storage trouble, without privileges (the tests run as root, which ignores permission bits): a
data directory deleted under the service, a full disk simulated by a file size limit
(RLIMIT_FSIZE), a storage error at start-up, and a kill -9 of a real `intspace serve` process
while a client posts observations."""

from __future__ import annotations

import json
import os
import resource
import shutil
import sqlite3
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.cli import main
from server.settings import Settings
from tests.support.hostile_requests import AUTH, TOKEN, connect, make_home
from tests.support.service import WITHOUT_TWIN, start_service


@pytest.fixture
def sqlite_client(tmp_path: Path, sqlite_template: Path) -> Iterator[tuple[TestClient, Path]]:
    """Return (a client of the real app on a SQLite file under its own data directory, that
    directory)."""
    data = tmp_path / "data"
    data.mkdir()
    shutil.copyfile(sqlite_template, data / "intspace.sqlite3")
    settings = Settings(
        _env_file=None,
        data_dir=data,
        admin_token=TOKEN,
        viser_enabled=False,
    )
    with TestClient(create_app(settings)) as client:
        yield client, data


def test_a_deleted_data_directory_makes_writes_fail_loudly(sqlite_client):
    client, data = sqlite_client
    assert client.post("/api/v1/spaces", json={"name": "before"}, headers=AUTH).status_code == 201
    shutil.rmtree(data)
    # Before: 201, the row written into the unlinked file and lost.
    response = client.post("/api/v1/spaces", json={"name": "after"}, headers=AUTH)
    assert response.status_code == 503, response.text
    detail = response.json()["detail"]
    assert "storage failing" in detail and "deleted" in detail
    assert response.headers["retry-after"]
    # /health says so too (before: "ok").
    health = client.get("/api/v1/health").json()
    assert health["status"] == "failing" and "deleted" in health["storage"], health


def test_a_full_disk_is_named_and_nothing_is_acknowledged(sqlite_client):
    client, data = sqlite_client
    used = sum(p.stat().st_size for p in data.iterdir())
    model = {"links": ["x" * 1000] * 90}  # ~90 kB of JSON per robot
    acknowledged, refusal = [], None
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    # No file may grow 1 MiB past what the database holds now: a disk that fills up. A soft
    # limit of this process, lifted right after (no privilege needed either way); Python ignores
    # SIGXFSZ, so a write past it fails (EFBIG) instead of killing the process.
    resource.setrlimit(resource.RLIMIT_FSIZE, (used + 2**20, hard))
    try:
        for i in range(100):
            response = client.post(
                "/api/v1/robots", json={"name": f"r{i}", "kinematic_model": model}, headers=AUTH
            )
            assert response.status_code != 500, response.text
            if response.status_code != 201:
                refusal = response
                break
            acknowledged.append(response.json()["id"])
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    assert refusal is not None, "the limit never bit"
    assert refusal.status_code in (503, 507), refusal.text
    assert "storage" in refusal.json()["detail"]
    # What was acknowledged is there; the service still answers.
    with sqlite3.connect(data / "intspace.sqlite3") as db:
        stored = {row[0] for row in db.execute("SELECT id FROM robots")}
    assert set(acknowledged) <= stored and len(acknowledged) > 0
    assert client.get("/api/v1/robots?limit=1", headers=AUTH).status_code == 200


def test_a_storage_error_at_start_up_is_one_line_and_exit_code_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    for name in [n for n in os.environ if n.startswith("INTSPACE_")]:
        monkeypatch.delenv(name)
    monkeypatch.setenv("INTSPACE_DATA_DIR", str(blocker / "data"))
    monkeypatch.setenv("INTSPACE_ADMIN_TOKEN", TOKEN)
    monkeypatch.setenv("INTSPACE_VISER_ENABLED", "false")
    monkeypatch.chdir(tmp_path)  # no .env of the work tree
    assert main(["serve", "--port", "1"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("intspace serve: storage error:") and "Not a directory" in line


def test_no_acknowledged_observation_is_lost_to_a_kill_9(repo_root: Path, tmp_path: Path):
    data = tmp_path / "data"
    service = start_service(data, token=TOKEN, env=WITHOUT_TWIN)
    home = make_home(service)
    cameras = [c["id"] for c in home["cameras"]]
    acknowledged: list[float] = []
    stop = threading.Event()

    def post_continuously() -> None:
        conn = connect(service)
        t = time.time()
        while not stop.is_set():
            t += 0.01
            batch = [{"camera_id": c, "t": t, "pixel": [640.0, 360.0]} for c in cameras]
            try:
                conn.request(
                    "POST", "/api/v1/observations", json.dumps({"observations": batch}), AUTH
                )
                response = conn.getresponse()
                response.read()
            except OSError:
                return  # the service died mid-request: that batch was never acknowledged
            if response.status == 200:
                acknowledged.append(t)

    client = threading.Thread(target=post_continuously)
    client.start()
    try:
        deadline = time.monotonic() + 20
        while len(acknowledged) < 150 and time.monotonic() < deadline:
            time.sleep(0.05)
        service.kill()
    finally:
        stop.set()
        client.join(timeout=30)
    assert len(acknowledged) >= 150
    # Restarted (in process: the same app and start-up, without a second interpreter's
    # seconds of imports) on the same data directory.
    settings = Settings(_env_file=None, data_dir=data, admin_token=TOKEN, viser_enabled=False)
    with TestClient(create_app(settings)) as restarted:
        assert restarted.get("/api/v1/health").status_code == 200
        with sqlite3.connect(data / "intspace.sqlite3") as db:
            stored = {
                round(t, 6)
                for (t,) in db.execute(
                    "SELECT t FROM detections GROUP BY t HAVING COUNT(*) = ?", (len(cameras),)
                )
            }
    missing = [t for t in acknowledged if round(t, 6) not in stored]
    assert not missing, f"{len(missing)} of {len(acknowledged)} acknowledged batches lost"
