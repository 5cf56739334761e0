"""The Navigation page in a real headless Chromium, on `intspace serve`.

Scenario: register the twin's home (its rooms: the service plans on the twin's walls and
furniture) and its projector at the nominal mount; sign in; on the Navigation page click a
start in the living room and a goal in the kitchen: the page plans the path and shows its length,
the one the service stored; follow it with the adaptive law: the status ends "succeeded" and the
tracking error is plotted (uPlot) with the service's series, and the robot and the spot are
drawn on the plan where the series ends.
"""

from __future__ import annotations

import math
import os

import pytest

from core.sim import default_scene

try:
    from playwright.sync_api import Page, expect
except ImportError:  # pragma: no cover - depends on the environment
    if os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no"):
        raise  # in CI the browser tests must run
    pytest.skip("playwright is not installed (pip install -e '.[dev]')", allow_module_level=True)

from tests.support.waiting import task_progress, wait_while_advancing

START, GOAL = (1.0, 2.5), (5.2, 1.45)


def _sign_in(page: Page, base_url: str, token: str) -> None:
    page.goto(f"{base_url}/")
    page.get_by_test_id("token-input").fill(token)
    page.get_by_test_id("token-submit").click()
    expect(page.get_by_test_id("sign-out")).to_be_visible()


def _click_world(page: Page, x: float, y: float) -> None:
    """Click the plan at world (x, y) metres through the page's own world -> SVG mapping."""
    cx, cy = page.evaluate(
        """([x, y]) => {
            const svg = document.querySelector('[data-testid="nav-map"]');
            const tf = JSON.parse(svg.dataset.transform);
            const u = tf.ox + (x - tf.x0) * tf.scale;
            const v = tf.height - tf.oy - (y - tf.y0) * tf.scale;
            const p = new DOMPoint(u, v).matrixTransform(svg.getScreenCTM());
            return [p.x, p.y];
        }""",
        [x, y],
    )
    page.mouse.click(cx, cy)


def test_navigation_page_plans_between_two_clicks_and_follows(service, browser_page: Page):
    page = browser_page
    scene = default_scene()
    space = service.api("POST", "/spaces", {"name": scene.name})["id"]
    for room in scene.rooms:
        polygon = [list(p) for p in room.polygon]
        service.api("POST", "/rooms", {"space_id": space, "name": room.name, "polygon": polygon})
    pose = scene.projector.pose
    service.api(
        "POST",
        "/projectors",
        {
            "name": "ceiling_projector",
            "space_id": space,
            "width": 1,
            "height": 1,
            "position": list(pose.position),
            "quaternion_xyzw": list(pose.quaternion_xyzw),
        },
    )
    _sign_in(page, service.base_url, service.token)
    page.get_by_test_id("nav-navigation").click()
    expect(page.get_by_test_id("nav-floor-plan")).to_contain_text("twin scene")
    # The projector with a pose is chosen; the walls and furniture of the twin's home are drawn.
    expect(page.get_by_test_id("nav-projector")).to_have_value("1")
    assert page.locator(".plan-furniture").count() == len(scene.furniture)

    _click_world(page, *START)
    expect(page.get_by_test_id("nav-start")).to_be_visible()
    _click_world(page, *GOAL)
    expect(page.get_by_test_id("nav-length")).to_be_visible()
    path_id = int(page.get_by_test_id("nav-path-id").inner_text().lstrip("#"))
    stored = service.api("GET", f"/paths/{path_id}")
    # The clicks land within a pixel of the intended points (about 1 cm at this plan's scale).
    for got, want in ((stored["start"], START), (stored["goal"], GOAL)):
        assert abs(got[0] - want[0]) < 0.02 and abs(got[1] - want[1]) < 0.02
    expect(page.get_by_test_id("nav-length")).to_have_text(f"{stored['length_m']:.2f} m")
    # Through the door between the rooms: a bend at its jamb.
    assert len(stored["points"]) >= 3
    expect(page.get_by_test_id("nav-path")).to_have_attribute(
        "data-points", str(len(stored["points"]))
    )
    expect(page.get_by_test_id("nav-duration")).to_be_visible()

    page.get_by_test_id("nav-law").select_option("adaptive")
    page.get_by_test_id("nav-follow").click()
    expect(page.get_by_test_id("follow-status")).to_be_visible()  # the task is started
    # Waited for while the following's state moves (idle until the page's request lands,
    # then its progress as it goes): a minute without a change is a follower that stopped,
    # not a busy machine.
    wait_while_advancing(
        lambda: service.api("GET", f"/paths/{path_id}")["follow"],
        done=lambda follow: follow["status"] in ("succeeded", "failed", "interrupted"),
        progress=task_progress,
        stalled_after_s=60.0,
        what="the path's following",
    )
    expect(page.get_by_test_id("follow-status")).to_have_text("succeeded")
    follow = service.api("GET", f"/paths/{path_id}")["follow"]
    assert follow["law"] == "adaptive"
    expect(page.get_by_test_id("follow-rms")).to_have_text(
        f"{follow['result']['rms_m'] * 1000:.1f} mm"
    )
    plot = page.get_by_test_id("nav-error-plot")
    expect(plot.locator("canvas")).to_be_visible()
    series = follow["series"]
    expect(plot).to_have_attribute("data-points", str(len(series["t"])))
    # The robot and the spot are drawn on the plan where the series' last sample has them,
    # with the robot's whole trail.
    robot, spot = page.get_by_test_id("nav-robot"), page.get_by_test_id("nav-spot")
    expect(robot).to_have_attribute("data-t", _js_number(series["t"][-1]))
    for key in ("x", "y", "theta"):
        expect(robot).to_have_attribute(f"data-{key}", _js_number(series[key][-1]))
    expect(spot).to_have_attribute("data-x", _js_number(series["spot_x"][-1]))
    expect(spot).to_have_attribute("data-y", _js_number(series["spot_y"][-1]))
    expect(page.get_by_test_id("nav-trail")).to_have_attribute("data-points", str(len(series["x"])))
    # The robot ends on the spot: its centre within the look-ahead (0.6 m) plus the final
    # tracking error of the spot, on the plan as in the series.
    box, dot = robot.locator("circle").bounding_box(), spot.bounding_box()
    assert box is not None and dot is not None
    scale = page.evaluate(
        "JSON.parse(document.querySelector('[data-testid=\"nav-map\"]').dataset.transform).scale"
    )
    ctm = page.evaluate("document.querySelector('[data-testid=\"nav-map\"]').getScreenCTM().a")
    gap = math.dist(
        (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2),
        (dot["x"] + dot["width"] / 2, dot["y"] + dot["height"] / 2),
    ) / (scale * ctm)
    want = math.dist(
        (series["x"][-1], series["y"][-1]), (series["spot_x"][-1], series["spot_y"][-1])
    )
    assert abs(gap - want) < 0.02  # a pixel or two of the plan's drawing, ~1 cm each


def _js_number(v: float) -> str:
    """Return `v` as JavaScript writes a number into an attribute (shortest round trip)."""
    return str(int(v)) if float(v).is_integer() else repr(float(v))
