"""Schemathesis over the whole OpenAPI schema: whatever the input, no 5xx (every backend)."""

from __future__ import annotations

import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis.checks import not_a_server_error

from server.app import create_app

# Thirty examples per operation keep the run to about 20 s on both backends; the
# generator still sends valid and invalid data to every operation.
EXAMPLES_PER_OPERATION = 30


def test_no_server_errors(make_settings, admin):
    # Runs are only queued (external executor): fuzzed correspondences are a concern of core's
    # own tests, not of HTTP.
    app = create_app(make_settings(run_executor="external"))
    schema = schemathesis.openapi.from_asgi("/api/v1/openapi.json", app)
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 30

    for operation in operations:

        @given(case=operation.as_strategy())
        @settings(
            max_examples=EXAMPLES_PER_OPERATION,
            deadline=None,
            suppress_health_check=list(HealthCheck),
            derandomize=True,
            database=None,
        )
        def check(case):
            case.call_and_validate(headers=admin, checks=[not_a_server_error])

        check()
    app.state.engine.dispose()
