"""The dashboard driven as a user drives it, for the browser tests: signing in with a token and
adding a camera through the cameras page's form."""

from __future__ import annotations

import re

from playwright.sync_api import Page, expect


def sign_in(page: Page, base_url: str, token: str) -> None:
    """Open the dashboard at `base_url`, sign in with `token` and wait until it is signed in."""
    page.goto(f"{base_url}/")
    page.get_by_test_id("token-input").fill(token)
    page.get_by_test_id("token-submit").click()
    expect(page.get_by_test_id("sign-out")).to_be_visible()


def add_camera(page: Page, name: str, width: int = 640, height: int = 480) -> int:
    """Add a camera through the cameras page's form; return its id once the page has moved to
    the new camera's detail."""
    page.get_by_test_id("nav-cameras").click()
    page.get_by_test_id("camera-name").fill(name)
    page.get_by_test_id("camera-width").fill(str(width))
    page.get_by_test_id("camera-height").fill(str(height))
    page.get_by_test_id("camera-create").click()
    page.wait_for_url(re.compile(r".*#/cameras/\d+$"))
    return int(page.url.rsplit("/", 1)[1])
