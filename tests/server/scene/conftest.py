"""The 3D scene's tests: a scene service on a free loopback port, stopped after the test."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest

from server.scene import SceneService


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def scene() -> Iterator[SceneService]:
    service = SceneService("127.0.0.1", _free_port())
    service.start()
    yield service
    service.stop()
