"""Every answer says the service's time to the microsecond (X-Server-Time), so a camera node's
first request already gives its clock offset; the node reads it from any answer."""

import time

import pytest

from server.node.client import ServiceClient


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_every_answer_carries_the_service_time_and_the_node_takes_it(client, admin):
    before = time.time()
    answers = [
        client.get("/api/v1/health"),
        client.get("/api/v1/cameras", headers=admin),
        client.get("/api/v1/cameras/99999", headers=admin),  # a 404 says it too
    ]
    after = time.time()
    for answer in answers:
        stamp = float(answer.headers["X-Server-Time"])
        assert before <= stamp <= after, (answer.request.url, stamp)

    node = ServiceClient("http://testserver/api/v1", "unused")
    node._http = client  # the app's own transport: same clock, so the offset is ~0
    node.request("GET", "/health")
    # One answer pins the offset to the round trip (here a few ms), not to Date's 2 s.
    assert node.clock.uncertainty < 0.5
    assert abs(node.offset) < node.clock.uncertainty + 1e-3
