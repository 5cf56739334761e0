"""The Landmarks page in a real headless Chromium, on `intspace serve`.

Scenario: register a calibrated head camera and two QR landmarks over the API; sign in; the
Landmarks page lists them with print links that serve the artwork at true size; upload a photo
rendered by the twin's landmark renderer (known truth) and pick the camera: both landmarks are
drawn over the photo with their labels, the object mark's outline on its true corners.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from core.landmarks import ObjectMark, Signpost, encode_payload
from core.landmarks.artwork import make_artwork
from core.sim.render import SensorNoise
from core.sim.render.landmarks import artwork_texture, render_landmarks
from tests.support.dashboard import sign_in
from tests.support.landmark_views import HEAD_CAMERA, mark_pose
from tests.support.landmark_views import HEAD_DIST as DIST
from tests.support.landmark_views import HEAD_K as K

try:
    from playwright.sync_api import Page, expect
except ImportError:  # pragma: no cover - depends on the environment
    if os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no"):
        raise  # in CI the browser tests must run
    pytest.skip("playwright is not installed (pip install -e '.[dev]')", allow_module_level=True)

CUP = ObjectMark(7, "cup", "blue cup", "kitchen", (0.08, 0.08, 0.1))
DOOR = Signpost(3, "kitchen door", "kitchen", (1.0, 2.0, 1.2, 0, 0, 0, 1), (4,))


def _photo(path: Path) -> np.ndarray:
    """Write the photo (PNG) of both landmarks at 30 deg; return the cup's true corners (4, 2)
    in distorted pixels."""
    cam = HEAD_CAMERA
    arts = [make_artwork(CUP), make_artwork(DOOR)]
    poses = [
        mark_pose(20.0, 30.0, [-0.12, 0.0, 0.45], 0.3),
        mark_pose(80.0, 30.0, [0.16, 0.0, 0.55], -0.4),
    ]
    view = render_landmarks(
        cam,
        [(artwork_texture(a), T, a.size, None) for a, T in zip(arts, poses, strict=True)],
        noise=SensorNoise(),
        rng=3,
    )
    cv2.imwrite(str(path), view.image)
    return view.truth[0].corners


def test_landmarks_page_prints_and_draws_detections(service, browser_page: Page, tmp_path: Path):
    page = browser_page
    camera = service.api(
        "POST", "/cameras", {"name": "head", "width": 640, "height": 480, "K": K, "dist": DIST}
    )
    cup = service.api(
        "POST", "/landmarks", {"kind": "qr", "payload": encode_payload(CUP), "size_m": 0.1}
    )
    service.api(
        "POST", "/landmarks", {"kind": "qr", "payload": encode_payload(DOOR), "size_m": 0.2}
    )
    photo = tmp_path / "photo.png"
    corners = _photo(photo)

    sign_in(page, service.base_url, service.token)
    page.get_by_test_id("nav-landmarks").click()
    expect(page.get_by_test_id(f"landmark-row-{cup['id']}")).to_contain_text("10.0 cm")
    link = page.get_by_test_id(f"print-svg-{cup['id']}")
    href = link.get_attribute("href")
    assert href == f"/api/v1/landmarks/{cup['id']}/print.svg"
    # The link works with the page's own sign-in (its cookie): true size in millimetres.
    svg = page.request.get(f"{service.base_url}{href}")
    assert svg.status == 200 and svg.headers["content-type"].startswith("image/svg+xml")
    assert re.search(r'width="120mm" height="140mm"', svg.text())

    page.get_by_test_id("landmark-photo").set_input_files(str(photo))
    page.get_by_test_id("detect-camera").select_option(str(camera["id"]))
    page.get_by_test_id("detect-submit").click()
    overlay = page.get_by_test_id("detection-overlay")
    expect(overlay).to_be_visible()
    expect(overlay.get_by_test_id("detection-outline")).to_have_count(2)
    expect(overlay).to_contain_text("#7 blue cup")
    expect(overlay).to_contain_text("#3 kitchen door")
    # The object mark's outline, as drawn, lies on its true corners: within a pixel (the
    # detector's corner accuracy at this size is ~0.1 px; the page draws what the API returns).
    drawn = page.evaluate(
        """() => [...document.querySelectorAll('[data-testid="detection-overlay"] .object polygon')]
              .map((p) => [...p.points].map((q) => [q.x, q.y]))"""
    )
    assert len(drawn) == 1 and len(drawn[0]) == 4
    d = np.linalg.norm(np.array(drawn[0])[:, None] - corners[None], axis=2)
    assert d.min(1).max() < 1.0, d.min(1)
    # The photo itself is drawn under the outlines, at its pixel size.
    assert overlay.get_attribute("viewBox") == "0 0 640 480"
    expect(page.get_by_test_id("detection-table")).to_contain_text("blue cup")

    # The maps: the registry has no space yet, and the page says so.
    expect(page.get_by_test_id("maps-missing")).to_contain_text("no space")
    # Enter the read landmarks into the maps (the camera at the world origin, facing +z) and
    # a second signpost (the hall door, a neighbour of the kitchen door): one object, two
    # places, one edge, drawn on the plan.
    service.api("POST", "/spaces", {"name": "home"})
    hall = Signpost(4, "hall door", "hall", (3.0, 2.0, 1.2, 0, 0, 0, 1), (3,))
    T = mark_pose(20.0, 30.0, [-0.12, 0.0, 0.45], 0.3).tolist()
    cov = np.diag([1e-4] * 3 + [1e-6] * 3).tolist()
    eye = np.eye(4).tolist()
    service.api(
        "POST",
        "/maps/observations",
        {
            "observations": [
                {"payload": encode_payload(r), "T_cam_mark": T, "cov": cov, "T_world_camera": eye}
                for r in (CUP, DOOR, hall, CUP)
            ]
        },
    )
    page.reload()
    plan = page.get_by_test_id("maps-plan")
    expect(plan.get_by_test_id("plan-object")).to_have_count(1)
    expect(plan.get_by_test_id("plan-place")).to_have_count(2)
    expect(plan.get_by_test_id("plan-edge")).to_have_count(1)
    expect(page.get_by_test_id("semantic-table")).to_contain_text("blue cup")
    expect(page.get_by_test_id("places-table")).to_contain_text("hall door")
