"""The harness that starts the service as a user starts it (tests/support/service.py): a
service that cannot start is an error that carries the service's own words, not a timeout."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.service import WITHOUT_TWIN, ServiceError, start_service

TOKEN = "service-harness-admin-token"


def test_a_service_that_exits_at_start_up_is_an_error_with_its_log(tmp_path: Path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    with pytest.raises(ServiceError) as caught:
        # A data folder below a file: `intspace serve` says why in one line and exits with 2.
        start_service(blocker / "data", token=TOKEN, env=WITHOUT_TWIN, log_path=tmp_path / "log")
    message = str(caught.value)
    assert "exited with 2 during start-up" in message, message
    assert "intspace serve: storage error:" in message and "Not a directory" in message, message
