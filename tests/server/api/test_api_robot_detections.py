"""A space with no registered robot makes no robot target (spec 08, "Real footage"): its
cameras' "robot" detections are ignored (not stored, not tracked, counted in the answer), the
people beside them go on; once a robot is registered in the space, the same detections are
stored and reach the space's tracker."""

from __future__ import annotations

import time

import numpy as np
import pytest

from core.localization import NetworkCamera
from tests.support.tracker_clock import HeldClock, wait_processed

K = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]
MARKER_HEIGHT = 0.36
PERSON_HEIGHT = 1.0


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_robot_detections_need_a_robot_in_the_space(client, admin):
    space = client.post("/api/v1/spaces", json={"name": "flat"}, headers=admin).json()["id"]
    cam = NetworkCamera.looking_at(K, None, [0.0, 0.0, 2.8], [2.0, 1.5, 0.0], (640, 480))
    body = {
        "name": "cam0",
        "width": 640,
        "height": 480,
        "space_id": space,
        "K": K,
        "T_world_camera": cam.T_world_camera.tolist(),
    }
    response = client.post("/api/v1/cameras", json=body, headers=admin)
    assert response.status_code == 201, response.text
    camera = response.json()["id"]
    tracking = client.app.state.runtime.tracking
    t0 = float(np.ceil(time.time())) + 10.0
    # The service's clock follows the frames, as live: the space's one camera releases each of
    # its frames at once by its own watermark.
    clock = HeldClock(t0)
    tracking._clock = clock

    def send(k0: int, n: int, with_person: bool) -> list[dict]:
        answers = []
        for k in range(k0, k0 + n):
            t = t0 + 0.1 * k
            clock.t = t + 0.05
            robot = cam.project([[1.5 + 0.02 * k, 1.0, MARKER_HEIGHT]])[0].tolist()
            obs = [
                {
                    "camera_id": camera,
                    "t": t,
                    "pixel": robot,
                    "kind": "robot",
                    "height": MARKER_HEIGHT,
                    "sigma_px": 0.5,
                }
            ]
            if with_person:
                person = cam.project([[2.5, 2.0, PERSON_HEIGHT]])[0].tolist()
                obs.append(
                    {
                        "camera_id": camera,
                        "t": t,
                        "pixel": person,
                        "kind": "person",
                        "height": PERSON_HEIGHT,
                        "sigma_px": 0.5,
                    }
                )
            r = client.post("/api/v1/observations", json={"observations": obs}, headers=admin)
            assert r.status_code == 200, r.text
            answers.append(r.json())
        return answers

    def robot_tracks() -> int:
        # The space's one tracker (tentative tracks too: any robot detection that reached it).
        return sum(x.kind == "robot" for x in tracking._spaces[space].tracker.tracks())

    base = tracking.frames_processed
    answers = send(0, 10, with_person=True)
    # The robot's detections are ignored, the person's stored and tracked.
    assert {(a["stored"], a["frames"], a["ignored"]) for a in answers} == {(1, 1, 1)}
    # A frame left with nothing still reaches the tracker, as an empty frame.
    answers = send(10, 10, with_person=False)
    assert {(a["stored"], a["frames"], a["ignored"]) for a in answers} == {(0, 1, 1)}
    wait_processed(tracking, base + 20)
    assert robot_tracks() == 0
    assert client.get("/api/v1/targets?state=all&kind=robot", headers=admin).json()["total"] == 0

    # A robot registered in the space: the same detections are stored and tracked.
    r = client.post("/api/v1/robots", json={"name": "r1", "space_id": space}, headers=admin)
    assert r.status_code == 201, r.text
    answers = send(20, 10, with_person=False)
    assert {(a["stored"], a["frames"], a["ignored"]) for a in answers} == {(1, 1, 0)}
    wait_processed(tracking, base + 30)
    assert robot_tracks() >= 1
