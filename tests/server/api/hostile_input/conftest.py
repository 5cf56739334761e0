"""One `intspace serve` for the hostile requests, without the twin, on a fresh data directory;
a keep-alive connection per test (`case`); and the space the requests aim at (`home`)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from tests.support.hostile_requests import TOKEN, Case, connect, make_home
from tests.support.service import WITHOUT_TWIN, Service, running_service


@pytest.fixture(scope="package")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """`intspace serve` without the twin on a fresh data directory."""
    with running_service(tmp_path_factory.mktemp("hostile"), token=TOKEN, env=WITHOUT_TWIN) as s:
        yield s


@pytest.fixture
def case(service: Service) -> Iterator[Case]:
    """A keep-alive connection to the service, closed after the test."""
    conn = connect(service)
    try:
        yield Case(service, conn)
    finally:
        conn.close()


@pytest.fixture(scope="package")
def home(service: Service) -> dict[str, Any]:
    """A space with one 8 x 6 m room and four posed ceiling cameras (as the twin's home)."""
    return make_home(service)
