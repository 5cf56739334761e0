"""Schemathesis over the whole OpenAPI schema: whatever the input, valid (positive generation)
or invalid (negative generation), no 5xx (every backend)."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error

from server.app import create_app

# Ten examples per operation and mode keep the run to about 20 s per mode on both
# backends.
EXAMPLES_PER_OPERATION = 10


@pytest.mark.parametrize("mode", list(GenerationMode), ids=lambda m: m.value)
def test_no_server_errors(make_settings, admin, mode):
    # Runs are only queued (external executor): fuzzed correspondences are a concern of core's
    # own tests, not of HTTP.
    app = create_app(make_settings(run_executor="external", auth_failure_limit="1000000/minute"))
    schema = schemathesis.openapi.from_asgi("/api/v1/openapi.json", app)
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 30

    fuzzed = 0
    for operation in operations:

        @given(case=operation.as_strategy(generation_mode=mode))
        @settings(
            max_examples=EXAMPLES_PER_OPERATION,
            deadline=None,
            suppress_health_check=list(HealthCheck),
            derandomize=True,
            database=None,
        )
        def check(case):
            case.call_and_validate(headers=admin, checks=[not_a_server_error])

        try:
            check()
        except Unsatisfiable:
            # No parameter and no body: nothing invalid can be sent to this operation.
            if mode is not GenerationMode.NEGATIVE:
                raise
            continue
        fuzzed += 1
    app.state.runtime.engine.dispose()
    assert fuzzed >= 30
