"""`intspace serve` as a real process, and `intspace db` in process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import httpx
import pytest
from alembic.script import ScriptDirectory

from server.cli import main
from server.db.migrate import alembic_config
from tests.support.service import start_service

# The newest migration: what a fresh database is upgraded to.
HEAD = ScriptDirectory.from_config(alembic_config("sqlite://")).get_current_head()


def test_serve_prints_urls_and_the_first_run_token_once(repo_root, tmp_path):
    first = start_service(tmp_path, wait=False)
    try:
        health = first.wait_healthy()
        assert health["database"] == "sqlite" and health["schema_revision"] == HEAD
        assert first.line("Dashboard: ") == f"Dashboard: http://127.0.0.1:{first.port}/"
        assert first.line("3D scene: ") == (
            f"3D scene: http://127.0.0.1:{first.port}/api/v1/scene/view/ (viser listens on "
            f"127.0.0.1:{first.viser_port} only; the API proxies it behind the sign-in)"
        )
        token_line = first.line("Admin token: ")
        assert token_line is not None
        token = token_line.split(": ", 1)[1]
        headers = {"Authorization": f"Bearer {token}"}
        base = f"http://127.0.0.1:{first.port}/api/v1"
        made = httpx.post(
            f"{base}/cameras", json={"name": "c", "width": 640, "height": 480}, headers=headers
        )
        assert made.status_code == 201, made.text
        assert httpx.get(f"http://127.0.0.1:{first.viser_port}/", timeout=5).status_code == 200
        # Secrets are never printed: the database URL has no password here, the token is
        # printed once on its own line only.
        assert sum(token in line for line in first.lines()) == 1
    finally:
        assert first.stop() == 0

    second = start_service(tmp_path)
    try:
        assert second.line("Dashboard: ") is not None
        assert second.line("Admin token: ") is None
        listed = httpx.get(f"http://127.0.0.1:{second.port}/api/v1/cameras", headers=headers)
        assert listed.status_code == 200 and listed.json()["total"] == 1
    finally:
        assert second.stop() == 0
    assert (tmp_path / "intspace.sqlite3").exists()


def test_db_upgrade_and_current(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("INTSPACE_DATABASE_URL", f"sqlite:///{tmp_path / 'db.sqlite3'}")
    assert main(["db", "current"]) == 1  # nothing applied yet
    assert "current: (none)" in capsys.readouterr().out
    assert main(["db", "upgrade"]) == 0
    assert f"revision {HEAD}" in capsys.readouterr().out
    assert main(["db", "current"]) == 0
    assert f"current: {HEAD}" in capsys.readouterr().out
    assert main(["db", "downgrade", "base"]) == 1
    out = capsys.readouterr().out
    assert "Backup: " in out and "current: (none)" in out


@pytest.mark.parametrize("argv", [["db"], ["serve", "--port", "not-a-port"]])
def test_bad_arguments_exit_with_usage(argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2


def test_worker_process_executes_queued_runs(
    make_settings, admin, run_waiter, repo_root, database_url, shared_data_dir
):
    import numpy as np
    from fastapi.testclient import TestClient

    from server.app import create_app

    data = shared_data_dir / "zhang1998"
    model = np.loadtxt(data / "Model.txt").reshape(-1, 2)
    object_points = np.column_stack([model, np.zeros(len(model))]).tolist()
    image_points = [np.loadtxt(data / f"data{i}.txt").reshape(-1, 2).tolist() for i in (1, 2, 3)]

    env = {k: v for k, v in os.environ.items() if not k.startswith("INTSPACE_")}
    env["INTSPACE_DATABASE_URL"] = database_url
    worker = subprocess.Popen(
        [sys.executable, "-m", "server.cli", "worker", "--poll", "0.2"],
        cwd=repo_root,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        with TestClient(create_app(make_settings(run_executor="external"))) as client:
            camera = client.post(
                "/api/v1/cameras", json={"name": "c", "width": 640, "height": 480}, headers=admin
            ).json()
            body = {
                "kind": "intrinsics",
                "camera_id": camera["id"],
                "image_size": [640, 480],
                "object_points": [object_points] * 3,
                "image_points": image_points,
            }
            run_id = client.post("/api/v1/calibration-runs", json=body, headers=admin).json()["id"]
            run = run_waiter(client, run_id)
        assert run["status"] == "succeeded", run["error"]
    finally:
        worker.send_signal(signal.SIGTERM)
        output, _ = worker.communicate(timeout=20)
    assert worker.returncode == 0, output
    assert f"run {run_id} succeeded" in output
