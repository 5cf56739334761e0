"""What the app does to its process while it runs, and undoes when it stops."""

from __future__ import annotations

import gc

from fastapi.testclient import TestClient

from server.app import create_app


def test_startup_objects_are_frozen_while_serving_and_released_at_shutdown(make_settings):
    # Frozen start-up objects keep full collections short under load (bench_soak_two_processes);
    # a process that makes and stops several apps must not keep every one of them for good.
    assert gc.get_freeze_count() == 0
    with TestClient(create_app(make_settings())) as client:
        assert client.get("/api/v1/health").status_code == 200
        assert gc.get_freeze_count() > 10_000
    assert gc.get_freeze_count() == 0
