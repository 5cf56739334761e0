"""The 3D scene's tests: a scene service on a free loopback port, stopped after the test."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from server.scene import SceneService
from tests.support.ports import free_port


@pytest.fixture
def scene() -> Iterator[SceneService]:
    service = SceneService("127.0.0.1", free_port())
    service.start()
    yield service
    service.stop()
