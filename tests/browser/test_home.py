"""The home integration in a real headless Chromium: `intspace serve` with INTSPACE_MQTT_URL on a
real broker (mosquitto). The Overview page shows the broker connected with its URL's password
masked, then disconnected once the broker is killed; the Floor page draws a zone with its name
and live occupancy, which goes to 1 when a person (three cameras' detections of a point inside
it) stands there."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

from tests.support.mqtt_broker import PASSWORD, broker  # noqa: F401
from tests.support.walking_person import camera_body, corner_cameras

try:
    from playwright.sync_api import expect
except ImportError:  # pragma: no cover - depends on the environment
    if os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no"):
        raise
    pytest.skip("playwright is not installed (pip install -e '.[dev]')", allow_module_level=True)

from tests.support.dashboard import sign_in


def test_overview_shows_the_broker_and_the_floor_draws_zone_occupancy(
    broker,  # noqa: F811
    start_service,
    browser_page,
):
    env = {"INTSPACE_MQTT_URL": broker.url, "INTSPACE_TRACKER_LATENCY_S": "0.3"}
    with start_service(env) as svc:
        assert PASSWORD not in svc.log()
        sid = svc.api("POST", "/spaces", {"name": "Flat"})["id"]
        svc.api(
            "POST",
            "/rooms",
            {"space_id": sid, "name": "Living", "polygon": [[0, 0], [5, 0], [5, 4], [0, 4]]},
        )
        zone = svc.api(
            "POST",
            f"/spaces/{sid}/zones",
            {"name": "Sofa", "polygon": [[0, 0], [2, 0], [2, 3], [0, 3]], "inertia_s": 0.3},
        )
        cams = corner_cameras()
        ids = [
            svc.api("POST", "/cameras", camera_body(f"cam{k}", sid, cam))["id"]
            for k, cam in enumerate(cams)
        ]
        page = browser_page
        sign_in(page, svc.base_url, svc.token)
        page.goto(f"{svc.base_url}/#/overview")
        expect(page.get_by_test_id("mqtt-state")).to_have_text("connected")
        expect(page.get_by_test_id("mqtt-url")).to_have_text(
            f"mqtt://intspace:***@127.0.0.1:{broker.port}"
        )
        assert PASSWORD not in page.content()

        page.goto(f"{svc.base_url}/#/floor")
        drawn = page.get_by_test_id(f"zone-{zone['id']}")
        expect(drawn).to_have_attribute("data-occupancy", "0")
        expect(drawn.locator("text")).to_have_text("Sofa: 0")
        expect(page.get_by_test_id("floor-zones").locator("polygon")).to_have_count(1)

        # A person stands at (1, 1.5), inside the zone, seen by the three cameras at 10 Hz.
        stop = threading.Event()

        def stand() -> None:
            X = np.array([[1.0, 1.5, 1.0]])
            while not stop.is_set():
                t = time.time()
                obs = [
                    {
                        "camera_id": cid,
                        "t": t,
                        "pixel": cam.project(X)[0].tolist(),
                        "sigma_px": 0.5,
                        "kind": "person",
                        "height": 1.0,
                    }
                    for cid, cam in zip(ids, cams, strict=True)
                ]
                svc.api("POST", "/observations", {"observations": obs})
                stop.wait(0.1)

        walker = threading.Thread(target=stand, daemon=True)
        walker.start()
        try:
            expect(drawn).to_have_attribute("data-occupancy", "1")
            expect(drawn.locator("polygon")).to_have_class("zone occupied")
        finally:
            stop.set()
            walker.join(5)

        broker.kill()
        page.goto(f"{svc.base_url}/#/overview")
        expect(page.get_by_test_id("mqtt-state")).to_have_text("disconnected")
    assert PASSWORD not in svc.log()
