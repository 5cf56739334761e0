"""The dashboard in a real headless Chromium against `intspace serve` started as a user starts it.

Scenario: sign in with the admin token, add a camera, calibrate it from Zhang's published
correspondences (a JSON file picked in the page), apply the result, read the intrinsics, export
them, and find the camera in the live 3D scene.

Screenshots go to the test's temporary directory; with INTSPACE_UPDATE_DOCS=1 the overview is
also written to docs/dashboard.png (the README's picture).
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from tests.browser.conftest import assert_scene_frame_is_proxied
from tests.support.camera_poses import look_at
from tests.support.dashboard import add_camera, sign_in
from tests.support.waiting import wait_for_run

try:
    from playwright.sync_api import Page, expect
except ImportError:  # pragma: no cover - depends on the environment
    if os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no"):
        raise  # in CI the browser tests must run
    pytest.skip("playwright is not installed (pip install -e '.[dev]')", allow_module_level=True)

DOCS_SCREENSHOT = Path(__file__).resolve().parents[2] / "docs" / "dashboard.png"

# Zhang's published focal lengths (alpha = 832.5, beta = 832.53, MSR-TR-98-71); a maximum-
# likelihood fit with skew and k1, k2 reproduces every printed digit, so 0.05 px is generous.
ZHANG_FX, ZHANG_FY = 832.5, 832.53
ZHANG_TOL = 0.05
# A camera without intrinsics is drawn with a 60 degree vertical field of view.
DEFAULT_FOV = math.radians(60.0)


def _wait_for_run(service, run_id: int) -> None:
    """Wait for a calibration run to end while its progress moves (tests/support/waiting.py).
    These runs report each image or stage within seconds; a minute without a change is a
    run that stopped, not a busy machine."""
    wait_for_run(
        lambda: service.api("GET", f"/calibration-runs/{run_id}"),
        stalled_after_s=60.0,
        poll_s=0.25,
    )


def wait_for_scene(read_scene, port: int, predicate, timeout: float = 3.0) -> dict:
    """Read the scene until `predicate(nodes)` holds; return the nodes (or the last read)."""
    deadline = time.monotonic() + timeout
    while True:
        nodes = read_scene(port)
        if predicate(nodes) or time.monotonic() > deadline:
            return nodes
        time.sleep(0.1)


def test_first_page_interactive_and_sign_in(
    service, browser_page: Page, tmp_path: Path, capsys: pytest.CaptureFixture
):
    page = browser_page
    t0 = time.perf_counter()
    page.goto(f"{service.base_url}/")
    # A function, not an expression string: the page's CSP forbids evaluating strings.
    page.wait_for_function("() => document.documentElement.dataset.ready === 'true'")
    expect(page.get_by_test_id("token-input")).to_be_editable()
    wall_ms = (time.perf_counter() - t0) * 1000.0
    in_page_ms = page.evaluate("window.intspaceReadyAt")
    with capsys.disabled():  # shown on every run, not only with -s
        print(
            f"\nfirst page interactive: {in_page_ms:.0f} ms after navigation start "
            f"({wall_ms:.0f} ms wall clock from goto, headless Chromium, loopback)"
        )
    # Without a token the page says what to do rather than showing empty data.
    expect(page.get_by_test_id("page-error")).to_contain_text("access token")
    expect(page).to_have_title(re.compile("intspace"))
    favicon = page.request.get(f"{service.base_url}/favicon.svg")
    assert favicon.ok and "svg" in favicon.headers["content-type"]

    page.get_by_test_id("token-input").fill("not-the-token")
    page.get_by_test_id("token-submit").click()
    expect(page.get_by_test_id("auth-status")).to_have_text("Token refused")
    assert page.evaluate("localStorage.length + sessionStorage.length") == 0

    page.get_by_test_id("token-input").fill(service.token)
    page.get_by_test_id("token-submit").click()
    expect(page.get_by_test_id("sign-out")).to_be_visible()
    expect(page.get_by_test_id("health-database")).to_have_text("sqlite")
    # Health in words, not raw values ("Scene: true").
    expect(page.get_by_test_id("health-storage")).to_have_text("working")
    expect(page.get_by_test_id("health")).not_to_contain_text("true")
    expect(page.get_by_test_id("count-cameras")).to_contain_text("0")

    # The page holds no token: the service's HttpOnly session cookie carries the sign-in.
    assert page.evaluate("localStorage.length + sessionStorage.length") == 0
    assert page.evaluate("document.cookie") == ""
    # Signed in, a reload shows the overview with its data: the cookie outlives the page.
    t0 = time.perf_counter()
    page.reload()
    expect(page.get_by_test_id("device-counts")).to_be_visible()
    with capsys.disabled():
        print(f"overview with data after reload: {(time.perf_counter() - t0) * 1000:.0f} ms")
    page.screenshot(path=tmp_path / "overview.png", full_page=True)

    page.get_by_test_id("sign-out").click()
    expect(page.get_by_test_id("token-input")).to_be_visible()
    assert not [c for c in page.context.cookies() if c["name"] == "intspace_session"]
    expect(page.get_by_test_id("page-error")).to_contain_text("access token")

    # A session the service ends (its token revoked) is noticed on the next request, and the
    # page says so.
    read = service.api("POST", "/tokens", {"name": "viewer", "scopes": ["read"]})
    page.get_by_test_id("token-input").fill(read["token"])
    page.get_by_test_id("token-submit").click()
    expect(page.get_by_test_id("auth-status")).to_have_text("Signed in (read)")
    expect(page.get_by_test_id("device-counts")).to_be_visible()
    service.api("DELETE", f"/tokens/{read['id']}")
    page.get_by_test_id("nav-cameras").click()
    expect(page.get_by_test_id("auth-status")).to_have_text("Session ended; sign in again")
    expect(page.get_by_test_id("page-error")).to_contain_text("access token")
    assert not [c for c in page.context.cookies() if c["name"] == "intspace_session"]


def test_calibrate_apply_export_and_see_the_camera_in_the_scene(
    service, browser_page: Page, zhang_json: Path, scene_reader, tmp_path: Path
):
    page = browser_page
    sign_in(page, service.base_url, service.token)

    # Add the camera through the form; the page moves to its detail.
    camera_id = add_camera(page, "pulnix-zhang")
    expect(page.get_by_test_id("camera-uncalibrated")).to_be_visible()
    expect(page.get_by_test_id("camera-no-pose")).to_be_visible()

    # The scene server already draws it: parked, greyed, with the default field of view.
    frustum = f"/cameras/{camera_id}/frustum"
    nodes = wait_for_scene(scene_reader, service.viser_port, lambda n: frustum in n)
    assert nodes[frustum]["type"] == "CameraFrustumMessage"
    assert nodes[frustum]["props"]["fov"] == pytest.approx(DEFAULT_FOV, abs=1e-12)
    label = nodes[f"/cameras/{camera_id}/label"]["props"]["text"]
    assert label == "pulnix-zhang (uncalibrated pose)"

    # Start a run from the correspondences file, picked through the file input.
    page.get_by_test_id("calibrate-camera").click()
    expect(page.get_by_test_id("run-camera")).to_have_value(str(camera_id))
    page.get_by_test_id("run-json-file").set_input_files(zhang_json)
    expect(page.get_by_test_id("json-summary")).to_contain_text("5 views, 1280 points")
    page.get_by_test_id("run-distortion").select_option("k1k2")
    page.get_by_test_id("run-skew").check()
    page.get_by_test_id("run-submit").click()
    page.wait_for_url(re.compile(r".*#/calibration/runs/\d+$"))
    run_id = int(page.url.rsplit("/", 1)[1])
    _wait_for_run(service, run_id)
    expect(page.get_by_test_id("run-status")).to_have_text("succeeded")

    run = service.api("GET", f"/calibration-runs/{run_id}")
    K = np.array(run["result"]["K"])
    assert K[0, 0] == pytest.approx(ZHANG_FX, abs=ZHANG_TOL)
    assert K[1, 1] == pytest.approx(ZHANG_FY, abs=ZHANG_TOL)
    expect(page.get_by_test_id("run-fx")).to_contain_text(f"{K[0, 0]:.3f}")
    expect(page.get_by_test_id("run-fx")).to_contain_text("832.5")
    expect(page.get_by_test_id("run-rms")).to_contain_text(f"{run['result']['rms']:.4f} px")

    # One bar per view, each the API's per-view RMS.
    bars = page.locator("[data-testid^='residual-bar-']")
    expect(bars).to_have_count(5)
    drawn = [float(bars.nth(i).get_attribute("data-value")) for i in range(5)]
    np.testing.assert_allclose(drawn, run["result"]["per_view_rms"], rtol=0, atol=1e-12)
    page.screenshot(path=tmp_path / "run.png", full_page=True)

    # Apply, then read the camera's new intrinsics on its page.
    page.get_by_test_id("run-apply").click()
    expect(page.get_by_test_id("run-applied")).to_be_visible()
    page.get_by_test_id("run-camera-link").click()
    expect(page.get_by_test_id("camera-fx")).to_contain_text(f"{K[0, 0]:.3f}")
    expect(page.get_by_test_id("camera-fy")).to_contain_text(f"{K[1, 1]:.3f}")
    std_fx = run["result"]["std_intrinsics"]["fx"]
    expect(page.get_by_test_id("camera-fx")).to_contain_text(f"± {std_fx:.3f}")
    expect(page.get_by_test_id("camera-K")).to_contain_text("832.5")
    history = page.get_by_test_id("calibration-history").locator("tbody tr")
    expect(history).to_have_count(1)
    expect(history.first).to_contain_text(f"#{run_id}")
    page.screenshot(path=tmp_path / "camera.png", full_page=True)

    # Export: the OpenCV file carries the same K (read back with OpenCV itself).
    with page.expect_download() as download_info:
        page.get_by_test_id("export-opencv").click()
    exported = tmp_path / "exported.yaml"
    download_info.value.save_as(exported)
    fs = cv2.FileStorage(str(exported), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(fs.getNode("camera_matrix").mat(), K, rtol=1e-9)
    fs.release()
    with page.expect_download() as download_info:
        page.get_by_test_id("export-ros").click()
    ros = tmp_path / "camera_info.yaml"
    download_info.value.save_as(ros)
    info = yaml.safe_load(ros.read_text())
    assert (info["image_width"], info["image_height"]) == (640, 480)
    np.testing.assert_allclose(np.reshape(info["camera_matrix"]["data"], (3, 3)), K, rtol=1e-12)

    # The embedded scene: the iframe shows the viser page the service proxies (viser itself
    # listens on loopback only), reached with the session cookie.
    page.get_by_test_id("nav-scene").click()
    viser_url = service.api("GET", "/scene")["viser_url"]
    assert viser_url == f"{service.base_url}/api/v1/scene/view/"
    iframe = page.get_by_test_id("scene-iframe")
    expect(iframe).to_have_attribute("src", "/api/v1/scene/view/")
    frame = iframe.element_handle().content_frame()
    frame.wait_for_load_state()
    assert_scene_frame_is_proxied(frame, service.base_url)
    assert "viser" in frame.content().lower()

    # And the scene server draws the applied intrinsics: fov = 2 atan(h / 2 fy).
    expected_fov = 2.0 * math.atan(480 / (2.0 * K[1, 1]))
    nodes = wait_for_scene(
        scene_reader,
        service.viser_port,
        lambda n: abs(n[frustum]["props"]["fov"] - expected_fov) < 1e-9,
    )
    assert nodes[frustum]["props"]["fov"] == pytest.approx(expected_fov, abs=1e-9)
    assert nodes[frustum]["props"]["aspect"] == pytest.approx(640 / 480, abs=1e-12)

    # A floor plan and two posed ceiling cameras, added through the API, appear on the overview
    # and in the scene at exactly their poses.
    space = service.api("POST", "/spaces", {"name": "Apartment 4B", "description": "Test flat"})
    rooms = [
        ("Living room", [[0, 0], [6, 0], [6, 3], [3.5, 3], [3.5, 5], [0, 5]]),
        ("Kitchen", [[6, 0], [9, 0], [9, 3], [6, 3]]),
        ("Study", [[3.5, 3], [6, 3], [6, 5], [3.5, 5]]),
    ]
    room_ids = [
        service.api("POST", "/rooms", {"space_id": space["id"], "name": n, "polygon": p})["id"]
        for n, p in rooms
    ]
    poses = {
        "ceiling-living": look_at([0.4, 4.6, 2.6], [3.0, 2.0, 0.0]),
        "ceiling-kitchen": look_at([8.6, 2.6, 2.5], [7.0, 1.0, 0.0]),
    }
    posed_ids = {}
    for name, T in poses.items():
        body = {"name": name, "width": 1280, "height": 720, "T_world_camera": T.tolist()}
        body["K"] = [[910.0, 0.0, 640.0], [0.0, 910.0, 360.0], [0.0, 0.0, 1.0]]
        posed_ids[name] = service.api("POST", "/cameras", body)["id"]

    # The embedded viewer shares the page's origin, hence its renderer's main thread, and
    # headless Chromium draws WebGL on the CPU: leave it by one navigation rather than a click's
    # several round trips through a busy thread.
    page.goto(f"{service.base_url}/#/overview")
    n_cameras = service.api("GET", "/cameras?limit=1")["total"]
    expect(page.get_by_test_id("count-cameras").locator(".value")).to_have_text(str(n_cameras))
    expect(page.get_by_test_id("count-rooms").locator(".value")).to_have_text("3")
    plan = page.get_by_test_id("floorplan")
    expect(plan.locator("polygon.room")).to_have_count(3)
    expect(plan.locator("circle.cam")).to_have_count(2)
    expect(page.get_by_test_id("recent-runs")).to_contain_text(f"#{run_id}")

    nodes = wait_for_scene(
        scene_reader,
        service.viser_port,
        lambda n: all(f"/cameras/{i}" in n for i in posed_ids.values()),
    )
    for room_id, (name, _) in zip(room_ids, rooms, strict=True):
        assert nodes[f"/floor/rooms/{room_id}/label"]["props"]["text"] == name
    for name, cam_id in posed_ids.items():
        # Positions travel as float64 on the wire; the rotation is checked in the unit tests.
        np.testing.assert_allclose(
            nodes[f"/cameras/{cam_id}"]["position"], poses[name][:3, 3], rtol=0, atol=1e-12
        )
        assert nodes[f"/cameras/{cam_id}/label"]["props"]["text"] == name

    page.evaluate("document.getElementById('toasts').replaceChildren()")  # earlier steps' notes
    page.screenshot(path=tmp_path / "dashboard.png")
    if os.environ.get("INTSPACE_UPDATE_DOCS") == "1":
        DOCS_SCREENSHOT.parent.mkdir(exist_ok=True)
        shutil.copyfile(tmp_path / "dashboard.png", DOCS_SCREENSHOT)


def test_problems_from_the_api_are_shown(
    service, browser_page: Page, zhang_document: dict, tmp_path: Path
):
    page = browser_page
    camera = service.api("POST", "/cameras", {"name": "hall", "width": 640, "height": 480})
    sign_in(page, service.base_url, service.token)
    page.goto(f"{service.base_url}/#/calibration?camera={camera['id']}")

    # The service refuses an image size of 0: its problem detail names the field.
    bad = tmp_path / "bad-size.json"
    bad.write_text(
        '{"image_size": [0, 480], "object_points": [[[0,0,0]]], "image_points": [[[1,1]]]}'
    )
    page.get_by_test_id("run-json-file").set_input_files(bad)
    page.get_by_test_id("run-submit").click()
    error = page.get_by_test_id("run-form-error")
    expect(error).to_be_visible()
    expect(error).to_contain_text("image_size")

    # A file that is not JSON is refused in the page, before anything is sent.
    junk = tmp_path / "junk.json"
    junk.write_text("not json")
    page.get_by_test_id("run-json-file").set_input_files(junk)
    expect(page.get_by_test_id("run-form-error")).to_contain_text("not valid JSON")

    # Two views cannot determine five intrinsics with skew: the run fails and says why.
    two = dict(zhang_document)
    two["object_points"], two["image_points"] = two["object_points"][:2], two["image_points"][:2]
    path = tmp_path / "two-views.json"
    path.write_text(json.dumps(two))
    page.get_by_test_id("run-json-file").set_input_files(path)
    page.get_by_test_id("run-skew").check()
    page.get_by_test_id("run-submit").click()
    page.wait_for_url(re.compile(r".*#/calibration/runs/\d+$"))
    run_id = int(page.url.rsplit("/", 1)[1])
    _wait_for_run(service, run_id)
    expect(page.get_by_test_id("run-status")).to_have_text(re.compile("failed|succeeded"))
    run = service.api("GET", f"/calibration-runs/{run_id}")
    assert run["status"] == "failed"
    expect(page.get_by_test_id("run-error")).to_contain_text(run["error"][:60])
    expect(page.get_by_test_id("run-apply")).to_have_count(0)


def test_calibrate_from_uploaded_chessboard_photos(
    service, browser_page: Page, chessboard_photos: list[Path]
):
    page = browser_page
    camera = service.api("POST", "/cameras", {"name": "desk", "width": 640, "height": 480})
    sign_in(page, service.base_url, service.token)
    page.goto(f"{service.base_url}/#/calibration?camera={camera['id']}")

    page.get_by_test_id("run-source-photos").check(force=True)  # the radio is styled as a tab
    expect(page.get_by_test_id("pane-photos")).to_be_visible()
    expect(page.get_by_test_id("pane-json")).to_be_hidden()
    page.get_by_test_id("run-files").set_input_files(chessboard_photos)
    page.get_by_test_id("run-chessboard").fill("9x6")
    page.get_by_test_id("run-square").fill("0.025")
    page.get_by_test_id("run-distortion").select_option("none")
    page.get_by_test_id("run-submit").click()
    page.wait_for_url(re.compile(r".*#/calibration/runs/\d+$"))
    _wait_for_run(service, int(page.url.rsplit("/", 1)[1]))
    expect(page.get_by_test_id("run-status")).to_have_text("succeeded")

    run_id = int(page.url.rsplit("/", 1)[1])
    run = service.api("GET", f"/calibration-runs/{run_id}")
    assert run["source"] == "images"
    K = np.array(run["result"]["K"])
    # The photos are rendered by fx = fy = 600, (cx, cy) = (320, 240). Anti-aliased rendering
    # leaves ~0.06 px corner noise (the run's RMS), which moves fx, fy, cx, cy by ~0.25 px here;
    # 1.5 px (0.25 %) keeps a margin and still catches a wrong board size or pixel convention.
    np.testing.assert_allclose(K[[0, 1, 0, 1], [0, 1, 2, 2]], [600, 600, 320, 240], atol=1.5)
    assert run["result"]["rms"] < 0.2
    expect(page.get_by_test_id("run-fx")).to_contain_text(f"{K[0, 0]:.3f}")
    expect(page.locator("[data-testid^='residual-bar-']")).to_have_count(len(chessboard_photos))
