"""Credentials in a real headless Chromium against `intspace serve` started as a user starts it.

Scenario: sign in through the page with a token an admin created, walk every page (the floor's
live WebSocket, the proxied 3D scene, the API docs served from the package), sign out. The token
travels once, in a POST body: it is in no URL the browser requested, in no storage the page
can read, and, once the service has stopped, in no line of its whole log (uvicorn's access log
included). The pages run under the service's Content-Security-Policy without a violation.
"""

from __future__ import annotations

import os
import re
from typing import Any

import pytest

try:
    from playwright.sync_api import expect
except ImportError:  # pragma: no cover - depends on the environment
    if os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no"):
        raise  # in CI the browser tests must run
    pytest.skip("playwright is not installed (pip install -e '.[dev]')", allow_module_level=True)

from tests.browser.conftest import assert_scene_frame_is_proxied, chromium_page
from tests.support.dashboard import add_camera


def test_a_browser_session_leaves_no_token_in_urls_storage_or_logs(
    start_service, chromium_executable: str
):
    secrets: dict[str, str] = {}
    requested: list[str] = []
    sockets: list[Any] = []
    scene_frames: list[int] = []
    violations: list[str] = []
    errors: list[str] = []
    with start_service() as svc:
        secrets["admin"] = svc.token
        created = svc.api("POST", "/tokens", {"name": "desk", "scopes": ["write"]})
        secrets["write"] = created["token"]
        camera = svc.api("POST", "/cameras", {"name": "door", "width": 640, "height": 480})
        with chromium_page(chromium_executable, 1280, 800) as page:
            context = page.context
            context.on("request", lambda r: requested.append(r.url))
            page.on("pageerror", lambda exc: errors.append(str(exc)))

            def on_console(message) -> None:
                if "Content Security Policy" in message.text:
                    violations.append(message.text)

            def on_socket(ws) -> None:
                sockets.append(ws)
                if ws.url.endswith("/api/v1/scene/view"):
                    ws.on("framereceived", lambda _payload: scene_frames.append(1))

            page.on("console", on_console)
            page.on("websocket", on_socket)

            page.goto(f"{svc.base_url}/")
            page.get_by_test_id("token-input").fill(secrets["write"])
            page.get_by_test_id("token-submit").click()
            expect(page.get_by_test_id("sign-out")).to_be_visible()
            expect(page.get_by_test_id("auth-status")).to_contain_text("write")
            expect(page.get_by_test_id("count-cameras")).to_contain_text("1")

            # The session lives in a cookie the page cannot read; nothing is stored.
            (cookie,) = [c for c in context.cookies() if c["name"] == "intspace_session"]
            assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
            secrets["session"] = cookie["value"]
            kept = page.evaluate(
                "JSON.stringify([{...localStorage}, {...sessionStorage}, document.cookie])"
            )
            assert kept == '[{},{},""]'

            # A write through the page (the CSRF token rides along): add a camera.
            add_camera(page, "hall")
            page.goto(f"{svc.base_url}/#/cameras/{camera['id']}")
            expect(page.get_by_test_id("camera-live-missing")).to_be_visible()

            # The floor's live positions come over a WebSocket the cookie opened.
            page.get_by_test_id("nav-floor").click()
            expect(page.get_by_test_id("positions-source")).to_have_attribute(
                "data-source", "websocket"
            )
            page.get_by_test_id("nav-calibration").click()
            expect(page.get_by_test_id("page-error")).to_have_count(0)

            # The 3D scene: the proxied viser page in the iframe, its WebSocket relayed.
            page.get_by_test_id("nav-scene").click()
            iframe = page.get_by_test_id("scene-iframe")
            expect(iframe).to_have_attribute("src", "/api/v1/scene/view/")
            frame = iframe.element_handle().content_frame()
            frame.wait_for_load_state()
            assert_scene_frame_is_proxied(frame, svc.base_url)
            frame.locator("canvas").first.wait_for(state="attached")
            # Playwright hands the socket's frames over only while it waits on the page: the
            # poll waits there.
            deadline_ms = 10_000
            while not scene_frames and deadline_ms > 0:
                page.wait_for_timeout(100)
                deadline_ms -= 100
            assert scene_frames, "the scene's WebSocket received nothing through the proxy"

            # The API docs: Swagger UI from the package, at /docs as the README says.
            page.goto(f"{svc.base_url}/docs")
            assert page.url == f"{svc.base_url}/api/v1/docs"
            expect(page.locator(".swagger-ui .info .title")).to_contain_text("intspace")
            expect(page.locator(".opblock-tag-section").first).to_be_visible()

            page.goto(f"{svc.base_url}/")
            page.get_by_test_id("sign-out").click()
            expect(page.get_by_test_id("token-input")).to_be_visible()
            assert not [c for c in context.cookies() if c["name"] == "intspace_session"]
        # The ended session is refused, even by a client that kept the cookie.
        import urllib.error
        import urllib.request

        request = urllib.request.Request(
            f"{svc.base_url}/api/v1/cameras",
            headers={"Cookie": f"intspace_session={secrets['session']}"},
        )
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(request, timeout=10)
        assert refused.value.code == 401
    log = svc.log()  # the service has stopped: this is everything it ever wrote

    assert not errors, f"JavaScript errors on the pages: {errors}"
    assert not violations, f"Content-Security-Policy violations: {violations}"
    assert {ws.url.rsplit("/api/v1", 1)[1] for ws in sockets} == {"/ws/targets", "/scene/view"}
    for name, secret in secrets.items():
        assert not [u for u in requested if secret in u], f"the {name} token was in a URL"
        hits = log.count(secret)
        assert hits == 0, f"the {name} token appears {hits} times in the service's log"
    assert "token=" not in log
    # The log is the whole of it: uvicorn's access log, WebSockets included, is in there.
    assert re.search(r'"POST /api/v1/session HTTP/1\.1" 200', log)
    assert re.search(r'"WebSocket /api/v1/ws/targets" \[accepted\]', log)
    assert re.search(r'"WebSocket /api/v1/scene/view" \[accepted\]', log)
