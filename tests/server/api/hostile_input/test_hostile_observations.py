"""Hostile observation batches: the largest ones cost bounded memory, a batch with many mistakes
gets the first twenty and their count, and live labels are bounded per space."""

from __future__ import annotations

import json
import time
from typing import Any

import pytest

from tests.support.hostile_requests import RSS_BOUND_MB


def _observations(n: int, camera_id: int, full: bool = False) -> list[dict[str, Any]]:
    extra = {"sigma_px": 1.5, "kind": "person", "height": 0.9} if full else {}
    return [
        {"camera_id": camera_id, "t": 1.0 + i * 1e-3, "pixel": [640.5, 360.25], **extra}
        for i in range(n)
    ]


@pytest.mark.parametrize("full", [True, False])
def test_the_largest_observation_batch_costs_bounded_memory(case, home, full):
    # The batch cap (20,000 observations with every field) and the body cap (4 MiB of the
    # smallest observations, ~90,000, more than the batch cap) both cost bounded memory.
    n = 20_000 if full else 4 * 2**20 // 58
    obs = _observations(n, 999_999, full=full)
    if full:
        for o in obs:
            o["cov"], o["target"] = [[1.25, 0.01], [0.01, 1.5]], "robot-1"
            del o["sigma_px"]
    body = json.dumps({"observations": obs}, separators=(",", ":")).encode()
    assert 2 * 2**20 < len(body) <= 4 * 2**20
    status, _, problem, growth, _ = case.send("POST", "/api/v1/observations", body)
    assert status == 422, problem
    if full:
        assert "observations.0.camera_id" in json.dumps(problem)
    else:
        assert "at most 20000 items" in json.dumps(problem)
    assert growth < RSS_BOUND_MB, growth
    case.next_request_answered()


def test_a_body_with_many_mistakes_gets_the_first_twenty_and_the_count(case, home):
    # 60,000 mistakes (four in each of 15,000 observations): the old answer listed every one
    # (8.8 MB).
    obs = _observations(15_000, 0)
    for o in obs:
        o["pixel"], o["t"] = ["x", "y"], "z"
    status, _, problem, growth, size = case.send(
        "POST", "/api/v1/observations", {"observations": obs}
    )
    assert status == 422
    assert problem["error_count"] == 60_000
    assert len(problem["errors"]) == 20
    assert "60000 in all" in problem["detail"]
    assert size < 20_000
    assert growth < RSS_BOUND_MB
    case.next_request_answered()


def _labelled(labels: list[str], camera_id: int) -> dict[str, Any]:
    t = time.time()
    return {
        "observations": [
            {"camera_id": camera_id, "t": t, "pixel": [600.0 + i % 50, 340.0], "target": label}
            for i, label in enumerate(labels)
        ]
    }


def test_live_labels_are_bounded_per_space(case, home):
    # Before: 40,000 labels became 40,000 live targets, each in every stream tick (7.8 MB).
    camera = home["cameras"][0]["id"]
    flood = [f"flood-{i}" for i in range(300)]
    status, _, problem, growth, _ = case.send(
        "POST", "/api/v1/observations", _labelled(flood, camera)
    )
    assert status == 422 and "at most 256 labelled targets" in problem["detail"]
    assert growth < RSS_BOUND_MB
    case.next_request_answered()
    first = [f"body-{i}" for i in range(250)]
    status, _, body, _, _ = case.send("POST", "/api/v1/observations", _labelled(first, camera))
    assert status == 200, body
    deadline = time.monotonic() + 30
    while True:
        status, _, page, _, _ = case.send("GET", "/api/v1/targets?limit=1")
        if page["total"] >= 250:
            break
        assert time.monotonic() < deadline, page["total"]
        time.sleep(0.2)
    more = [f"late-{i}" for i in range(10)]
    status, headers, problem, _, _ = case.send(
        "POST", "/api/v1/observations", _labelled(more, camera)
    )
    assert status == 429, problem
    assert headers["retry-after"] == "60" and "over the limit of 256" in problem["detail"]
    # Labels already live are still taken.
    status, _, _, _, _ = case.send("POST", "/api/v1/observations", _labelled(first[:5], camera))
    assert status == 200
    case.next_request_answered()
