"""Hostile requests to the calibration runs: a body over its endpoint's limit is refused unread,
and a boolean option must be a boolean."""

from __future__ import annotations

import json

import pytest

from tests.support.hostile_requests import RSS_BOUND_MB


def test_a_body_over_its_endpoints_limit_is_refused_unread(case, home):
    # 24 MB of correspondences cost the old service 0.3 GB (42 MB: 0.5-2.1 GB) to end in a 422;
    # 12 MB here, built as bytes (fast), are over the endpoint's 8 MiB.
    view = json.dumps([[float(i), float(j), 0.0] for i in range(20) for j in range(20)])
    pixels = json.dumps([[100.0 + i, 200.0 + j] for i in range(20) for j in range(20)])
    body = (
        f'{{"kind":"intrinsics","camera_id":{home["cameras"][0]["id"]},'
        f'"image_size":[1280,720],"object_points":[{",".join([view] * 900)}],'
        f'"image_points":[{",".join([pixels] * 900)}]}}'
    ).encode()
    assert len(body) > 9 * 2**20
    status, _, problem, growth, _ = case.send("POST", "/api/v1/calibration-runs", body)
    assert status == 413
    assert "limit of 8388608 bytes" in problem["detail"]
    assert growth < RSS_BOUND_MB
    case.next_request_answered()


@pytest.mark.parametrize("value", [1, "true", "yes"])
def test_booleans_are_booleans(case, value):
    # 1 is not true: a network run's study flag (the run needs the twin: 409 once valid).
    body = {"kind": "network", "options": {"study": value}}
    status, _, problem, _, _ = case.send("POST", "/api/v1/calibration-runs", body)
    assert status == 422, problem
    assert problem["errors"][0]["field"].endswith("study")
    status, _, _, _, _ = case.send(
        "POST", "/api/v1/calibration-runs", {"kind": "network", "options": {"study": True}}
    )
    assert status == 409
