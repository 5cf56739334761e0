"""Calibrating the projector from the Navigation page, in a real headless Chromium, on
`intspace serve` with the digital twin.

Scenario: the twin registers its home and its calibrated ceiling cameras; a projector is
entered without a mount pose (uncalibrated: no path can be drawn with it); sign in; on the
Navigation page click "Calibrate projector" (spots projected, for speed): the page follows the
run to "succeeded" and shows the service's fit; apply it: the projector now has that mount
and is offered for planning.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

try:
    from playwright.sync_api import Page, expect
except ImportError:  # pragma: no cover - depends on the environment
    if os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no"):
        raise  # in CI the browser tests must run
    pytest.skip("playwright is not installed (pip install -e '.[dev]')", allow_module_level=True)

from tests.support.waiting import wait_for_run


def test_navigation_page_calibrates_the_projector_and_applies_it(start_service, browser_page: Page):
    page = browser_page
    env = {"INTSPACE_SIMULATION": "true", "INTSPACE_TWIN_RATE_HZ": "0.5"}
    with start_service(env) as service:
        service.api("POST", "/twin/pause")  # the run projects the spots: no frames needed
        space = service.api("GET", "/spaces")["items"][0]["id"]  # the twin's home
        # The twin registered its projector with its home, uncalibrated.
        (projector,) = service.api("GET", f"/projectors?space_id={space}")["items"]
        assert projector["name"] == "ceiling_projector"
        assert projector["T_world_projector"] is None

        page.goto(f"{service.base_url}/")
        page.get_by_test_id("token-input").fill(service.token)
        page.get_by_test_id("token-submit").click()
        page.get_by_test_id("nav-navigation").click()
        expect(page.get_by_test_id("nav-floor-plan")).to_contain_text("twin scene")
        # Uncalibrated: not offered for planning, offered for calibration.
        expect(page.get_by_test_id("nav-projector")).to_have_value("")
        expect(page.get_by_test_id("calib-projector")).to_have_value(str(projector["id"]))

        page.get_by_test_id("calib-images").uncheck()
        page.get_by_test_id("calib-start").click()
        # The page names the run it started; waited for while its progress moves (a stage
        # every few seconds: a minute without a change is a run that stopped).
        expect(page.get_by_test_id("calib-run")).to_be_visible()
        run_id = int(page.get_by_test_id("calib-run").inner_text().lstrip("#"))
        wait_for_run(
            lambda: service.api("GET", f"/calibration-runs/{run_id}"), stalled_after_s=60.0
        )
        expect(page.get_by_test_id("calib-status")).to_have_text("succeeded")
        run = service.api("GET", f"/calibration-runs/{run_id}")
        assert run["kind"] == "projector" and run["options"]["images"] is False
        result = run["result"]
        assert result["projector_id"] == projector["id"]
        # The page shows the service's own fit.
        expect(page.get_by_test_id("calib-spots")).to_have_text(str(result["spots"]))
        expect(page.get_by_test_id("calib-rms")).to_have_text(f"{result['rms_m'] * 1000:.1f} mm")
        errors = result["twin_errors"]
        expect(page.get_by_test_id("calib-twin-errors")).to_have_text(
            f"{errors['position_m'] * 1000:.1f} mm, {errors['rotation_deg']:.3f}°"
        )
        # Spec 03 calibrates from 12 or more spots.
        assert result["spots"] >= 12

        page.get_by_test_id("calib-apply").click()
        expect(page.get_by_test_id("calib-apply")).to_have_text("Applied")
        # Applied: the projector has the fitted mount and is now chosen for planning.
        expect(page.get_by_test_id("nav-projector")).to_have_value(str(projector["id"]))
        stored = service.api("GET", f"/projectors/{projector['id']}")["T_world_projector"]
        np.testing.assert_allclose(stored, result["T_world_projector"], atol=0.0)
        history = service.api("GET", f"/projectors/{projector['id']}/calibrations")
        assert [e["calibration_run_id"] for e in history["items"]] == [run_id]
