"""Two spaces in the dashboard: the digital twin's home and a flat whose camera is registered
and fed through the REST API (detections with an ingest token, as a camera node sends them).

Each page shows only the space picked in the header: the flat's camera and its visitor are
absent from the home's pages and present on the flat's; the counts agree between pages; a twin
camera's page shows its health and its latest image; the choice is remembered by the browser
(localStorage holds the space's id, nothing else); the 3D scene follows it.
"""

from __future__ import annotations

import json
import os
import time
import urllib.request

import numpy as np
import pytest

from core.localization import NetworkCamera
from core.sim import default_scene
from tests.support.waiting import wait_until

try:
    from playwright.sync_api import Page, expect
except ImportError:  # pragma: no cover - depends on the environment
    if os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no"):
        raise  # in CI the browser tests must run
    pytest.skip("playwright is not installed (pip install -e '.[dev]')", allow_module_level=True)

K = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]
FLAT_ROOM = [[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]]
VISITOR = (2.0, 1.5)  # where the flat's visitor stands (m)


def _post(base_url: str, token: str, path: str, body: dict) -> dict:
    request = urllib.request.Request(
        f"{base_url}/api/v1{path}",
        method="POST",
        data=json.dumps(body).encode(),
        headers={"Authorization": f"Bearer {token}", "Content-Type": "application/json"},
    )
    with urllib.request.urlopen(request, timeout=10) as response:
        return json.loads(response.read())


def _pick(page: Page, space_id: int) -> None:
    page.get_by_test_id("space-picker").select_option(str(space_id))
    expect(page.get_by_test_id("space-picker")).to_have_value(str(space_id))


def test_every_page_shows_the_space_picked(start_service, browser_page: Page, scene_reader):
    page = browser_page
    scene = default_scene()
    env = {"INTSPACE_SIMULATION": "true", "INTSPACE_TWIN_RATE_HZ": "2"}
    with start_service(env) as service:
        home = service.api("GET", "/spaces")["items"][0]
        twin_cameras = service.api("GET", f"/cameras?space_id={home['id']}")["items"]
        assert len(twin_cameras) == len(scene.cameras)
        flat = service.api("POST", "/spaces", {"name": "Flat 2", "description": "a second home"})
        service.api(
            "POST", "/rooms", {"space_id": flat["id"], "name": "studio", "polygon": FLAT_ROOM}
        )
        lens = NetworkCamera.looking_at(K, None, [0.2, 0.2, 2.6], [2.0, 1.5, 0.0], (640, 480))
        door = service.api(
            "POST",
            "/cameras",
            {
                "name": "flat-door",
                "space_id": flat["id"],
                "width": 640,
                "height": 480,
                "K": K,
                "T_world_camera": lens.T_world_camera.tolist(),
            },
        )
        # The flat's camera node: its ingest token, a heartbeat and one labelled detection (a
        # labelled target stays live for a minute after its last detection).
        ingest = service.api(
            "POST",
            "/tokens",
            {"name": "flat-node", "scopes": ["ingest"], "camera_ids": [door["id"]]},
        )["token"]
        beat = {"fps": 10.0, "reconnects": 2, "last_frame_t": time.time()}
        _post(service.base_url, ingest, f"/cameras/{door['id']}/heartbeat", beat)
        pixel = lens.project(np.array([[*VISITOR, 0.0]]))[0].tolist()
        obs = {"camera_id": door["id"], "t": time.time(), "pixel": pixel, "target": "visitor"}
        _post(service.base_url, ingest, "/observations", {"observations": [obs]})

        # The twin's cameras come online with its first frames (it learns their backgrounds
        # first: seconds on a loaded machine).
        wait_until(
            lambda: all(
                c["health"]["status"] == "online"
                for c in service.api("GET", f"/cameras?space_id={home['id']}")["items"]
            ),
            what="the twin's cameras online",
            stalled_after_s=90,
            poll_s=0.5,
        )

        page.goto(f"{service.base_url}/")
        page.get_by_test_id("token-input").fill(service.token)
        page.get_by_test_id("token-submit").click()
        expect(page.get_by_test_id("sign-out")).to_be_visible()
        # The first space (the twin's home) until another is picked.
        expect(page.get_by_test_id("space-picker")).to_have_value(str(home["id"]))

        # -- the home ----------------------------------------------------------------------
        expect(page.get_by_test_id("space")).to_contain_text(home["name"])
        counts = page.get_by_test_id("count-cameras")
        expect(counts.locator(".value")).to_have_text(str(len(scene.cameras)))
        # "calibrated" means what the Cameras page's Status column says.
        expect(counts.locator(".sub")).to_contain_text(f"{len(scene.cameras)} calibrated")
        expect(page.get_by_test_id("count-landmarks").locator(".value")).to_have_text(
            str(len(scene.landmarks))
        )
        expect(page.get_by_test_id("count-projectors").locator(".value")).to_have_text("1")

        page.get_by_test_id("nav-cameras").click()
        table = page.get_by_test_id("camera-table")
        expect(table.locator("tbody tr")).to_have_count(len(scene.cameras))
        expect(table.locator(".badge.calibrated")).to_have_count(len(scene.cameras))
        expect(page.get_by_test_id(f"camera-row-{door['id']}")).to_have_count(0)
        first = twin_cameras[0]
        expect(page.get_by_test_id(f"camera-health-{first['id']}")).to_have_text("online")

        # A twin camera's page: its health as a node's, and its latest image.
        page.get_by_test_id(f"camera-row-{first['id']}").locator("a").click()
        expect(page.get_by_test_id("camera-health-status")).to_have_text("online")
        expect(page.get_by_test_id("camera-health-clock-offset")).to_have_text("0.0 ms")
        expect(page.get_by_test_id("camera-health-reconnects")).to_have_text("0")
        fps = float(page.get_by_test_id("camera-health-fps").inner_text().split()[0])
        assert 0.0 < fps <= 2.0 * 1.05  # at most the twin's rate, 2 frames a second
        expect(page.get_by_test_id("camera-health-since")).not_to_have_text("never reported")
        expect(page.get_by_test_id("camera-live-image")).to_be_visible()
        expect(page.get_by_test_id("camera-space")).to_have_text(home["name"])

        page.get_by_test_id("nav-floor").click()
        expect(page.get_by_test_id("twin-status")).to_be_visible()
        # The twin's robot is tracked here; the flat's visitor is not.
        expect(page.get_by_test_id("target-row-robot")).to_be_visible(timeout=40_000)
        expect(page.get_by_test_id("target-row-visitor")).to_have_count(0)
        expect(page.get_by_test_id("target-visitor")).to_have_count(0)
        expect(page.get_by_test_id("floor-map")).not_to_contain_text("flat-door")

        page.get_by_test_id("nav-landmarks").click()
        expect(page.get_by_test_id("landmark-table").locator("tbody tr")).to_have_count(
            len(scene.landmarks)
        )
        expect(page.get_by_test_id("landmark-table")).to_contain_text("object #1 blue cup")
        options = page.get_by_test_id("detect-camera").locator("option")
        expect(options).to_have_count(len(scene.cameras))
        expect(page.get_by_test_id("detect-camera")).not_to_contain_text("flat-door")
        expect(page.get_by_test_id("maps-plan").locator("polygon.room")).to_have_count(
            len(scene.rooms)
        )

        page.get_by_test_id("nav-navigation").click()
        expect(page.get_by_test_id("calib-projector")).to_contain_text(scene.projector.name)
        expect(page.get_by_test_id("calib-start")).to_be_enabled()

        # -- the flat -----------------------------------------------------------------------
        _pick(page, flat["id"])
        expect(page.get_by_test_id("calib-why")).to_contain_text("No projector is registered")
        expect(page.get_by_test_id("calib-start")).to_be_disabled()

        page.get_by_test_id("nav-overview").click()
        expect(page.get_by_test_id("space")).to_contain_text("Flat 2")
        counts = page.get_by_test_id("count-cameras")
        expect(counts.locator(".value")).to_have_text("1")
        # Registered with K by hand, not calibrated: the Cameras page says "uncalibrated" too.
        expect(counts.locator(".sub")).to_contain_text("0 calibrated")
        expect(page.get_by_test_id("count-landmarks").locator(".value")).to_have_text("0")

        page.get_by_test_id("nav-cameras").click()
        table = page.get_by_test_id("camera-table")
        expect(table.locator("tbody tr")).to_have_count(1)
        expect(page.get_by_test_id(f"camera-row-{door['id']}")).to_contain_text("uncalibrated")
        for camera in twin_cameras:
            expect(page.get_by_test_id(f"camera-row-{camera['id']}")).to_have_count(0)

        # Its node's heartbeat is its health; no image has reached the service.
        page.get_by_test_id(f"camera-row-{door['id']}").locator("a").click()
        expect(page.get_by_test_id("camera-health-reconnects")).to_have_text("2")
        expect(page.get_by_test_id("camera-health-fps")).to_have_text("10.0 /s")
        expect(page.get_by_test_id("camera-live-missing")).to_contain_text("No image yet")
        expect(page.get_by_test_id("camera-live-missing")).not_to_contain_text("not running")

        page.get_by_test_id("nav-floor").click()
        visitor = page.get_by_test_id("target-row-visitor")
        expect(visitor).to_contain_text("2.000")
        expect(visitor).to_contain_text("1.500")
        expect(page.get_by_test_id("target-row-robot")).to_have_count(0)
        expect(page.get_by_test_id("robot-truth")).to_have_count(0)
        expect(page.get_by_test_id("twin-elsewhere")).to_contain_text(home["name"])
        expect(page.get_by_test_id("floor-map")).to_contain_text("flat-door")
        expect(page.get_by_test_id("floor-map")).not_to_contain_text("cam_")

        # The 3D scene shows the flat: its camera, none of the home's, no twin robot.
        page.get_by_test_id("nav-scene").click()
        expect(page.get_by_test_id("scene-space")).to_have_text("Flat 2 in 3D")
        assert service.api("GET", "/scene")["space_id"] == flat["id"]

        def flat_scene() -> dict | None:
            nodes = scene_reader(service.viser_port)
            shown = {k.split("/")[2] for k in nodes if k.startswith("/cameras/")}
            return nodes if shown == {str(door["id"])} else None

        nodes = wait_until(
            flat_scene, what="the flat's camera alone in the scene", stalled_after_s=10, poll_s=0.2
        )
        assert not any(k.startswith("/agents/") for k in nodes)

        # Remembered by this browser, as an id and nothing else.
        page.reload()
        expect(page.get_by_test_id("space-picker")).to_have_value(str(flat["id"]))
        stored = page.evaluate("JSON.stringify(Object.assign({}, localStorage))")
        assert json.loads(stored) == {"intspace.space": str(flat["id"])}
