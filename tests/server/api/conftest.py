"""Fixtures the API tests share."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from server.app import create_app


@pytest.fixture
def paused_twin_client(make_settings, admin) -> Iterator[TestClient]:
    """A client of the app with the simulated home, its twin paused: the tests that need none of
    the twin's cameras (arms, tasks) leave the CPU to what they test."""
    settings = make_settings(simulation=True, twin_rate_hz=0.5)
    with TestClient(create_app(settings)) as client:
        client.post("/api/v1/twin/pause", headers=admin)
        yield client
