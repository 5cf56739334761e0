"""Every answer carries nosniff, a Referrer-Policy and a Content-Security-Policy; the dashboard and
the API docs run no inline script and load nothing from elsewhere; the docs' Swagger UI ships
with the package; no token reaches a log line."""

from __future__ import annotations

import logging
import re
import shutil
from html.parser import HTMLParser
from pathlib import Path

import pytest

from server.security import RedactSecrets, install_log_redaction

WEB = Path(__file__).resolve().parents[2] / "web"


@pytest.fixture
def database_url(tmp_path: Path, sqlite_template: Path) -> str:
    """Headers and pages do not depend on the database backend: SQLite only."""
    path = tmp_path / "intspace.sqlite3"
    shutil.copyfile(sqlite_template, path)
    return f"sqlite:///{path}"


class _Tags(HTMLParser):
    """Every start tag of a page with its attributes, and the text inside <script> tags."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.script_text: list[str] = []
        self._in_script = False

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        self._in_script = tag == "script"

    def handle_endtag(self, tag):
        self._in_script = False

    def handle_data(self, data):
        if self._in_script and data.strip():
            self.script_text.append(data)


def parse(html: str) -> _Tags:
    tags = _Tags()
    tags.feed(html)
    return tags


def directives(csp: str) -> dict[str, list[str]]:
    out = {}
    for part in csp.split(";"):
        name, *values = part.split()
        out[name] = values
    return out


def test_every_answer_carries_the_security_headers(client):
    # Anonymous: pages, API answers, refusals and misses alike.
    for path in ("/", "/index.html", "/api/v1/health", "/api/v1/cameras", "/api/v1/docs", "/x"):
        response = client.get(path)
        assert response.headers["x-content-type-options"] == "nosniff", path
        assert response.headers["referrer-policy"] == "same-origin", path
        csp = directives(response.headers["content-security-policy"])
        assert csp["frame-ancestors"] == ["'self'"], path  # only the service frames its pages
        assert csp["script-src"] == ["'self'"], path  # no inline script, no eval, no other host
        assert csp["object-src"] == ["'none'"], path
        assert "'unsafe-inline'" not in csp["style-src"], path


def test_the_dashboard_and_docs_pages_have_no_inline_script_and_no_remote_asset(client):
    pages = {"/": client.get("/").text, "/api/v1/docs": client.get("/api/v1/docs").text}
    pages.update({f"/{p.name}": p.read_text() for p in WEB.glob("*.html")})
    for path, html in pages.items():
        tags = parse(html)
        assert not tags.script_text, f"{path} has an inline script"
        for tag, attrs in tags.tags:
            assert not [a for a in attrs if a.startswith("on")], f"{path}: handler on <{tag}>"
            assert "style" not in attrs, f"{path}: style attribute on <{tag}>"
            for key in ("src", "href"):
                value = attrs.get(key) or ""
                assert not re.match(r"^(https?:)?//", value), f"{path} loads {value}"
    # The page code never builds markup with inline handlers or style strings either.
    for js in WEB.glob("js/**/*.js"):
        text = js.read_text()
        assert not re.search(r"setAttribute\(\s*[\"']style[\"']", text), js
        # Browser storage holds the chosen space's id (one number, no secret) and nothing else.
        stored = re.findall(r"(?:localStorage|sessionStorage)\.(\w+)\(([^,)]*)", text)
        assert all(key.strip() == "SPACE_KEY" for _, key in stored), (js, stored)
        assert "sessionStorage" not in text, js
        assert "token=" not in text, js


def test_the_api_docs_are_served_from_the_package(client):
    redirect = client.get("/docs", follow_redirects=False)
    assert redirect.status_code == 308 and redirect.headers["location"] == "/api/v1/docs"
    page = client.get("/api/v1/docs")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"]
    sources = [a.get("src") or a.get("href") for _, a in parse(page.text).tags]
    assert "/vendor/swagger-ui/swagger-ui-bundle.js" in sources
    assert "/vendor/swagger-ui/swagger-ui.css" in sources
    bundle = client.get("/vendor/swagger-ui/swagger-ui-bundle.js")
    assert bundle.status_code == 200 and "javascript" in bundle.headers["content-type"]
    assert len(bundle.content) > 1_000_000 and b"SwaggerUIBundle" in bundle.content
    css = client.get("/vendor/swagger-ui/swagger-ui.css")
    assert css.status_code == 200 and b".swagger-ui" in css.content
    assert client.get("/api/v1/openapi.json").json()["info"]["title"] == "intspace"


def test_the_proxied_scene_page_alone_may_run_viser_inline_code(make_settings):
    from fastapi.testclient import TestClient

    from server.app import create_app

    with TestClient(create_app(make_settings())) as client:
        response = client.get("/api/v1/scene/view/")  # refused (no credential): headers still
    csp = directives(response.headers["content-security-policy"])
    assert "'unsafe-inline'" in csp["script-src"]
    assert csp["frame-ancestors"] == ["'self'"] and csp["connect-src"][0] == "'self'"


def test_tokens_are_redacted_from_log_lines(caplog):
    secret = "configured-admin-secret-0123456789"
    install_log_redaction([secret])
    try:
        log = logging.getLogger("uvicorn.access")
        lines = [
            (
                '%s - "%s %s HTTP/%s" %d',
                ("127.0.0.1:5", "GET", "/api/v1/ws/targets?token=abc123def456", "1.1", 200),
            ),
            ("header Authorization: Bearer %s", (secret,)),
            ("token %s created", ("isp_Yx3fQ9kLmN0pRsTuVwXyZ012345678",)),
            ("cookie intspace_session=%s", ("iss_AbCdEfGhIjKlMnOpQrStUv",)),
        ]
        with caplog.at_level(logging.INFO, logger="uvicorn.access"):
            for msg, args in lines:
                log.info(msg, *args)
        text = caplog.text
        for leaked in ("abc123def456", secret, "isp_Yx3f", "iss_AbCd"):
            assert leaked not in text
        assert text.count("[redacted]") == 4
        assert "/api/v1/ws/targets?token=[redacted]" in text
    finally:
        install_log_redaction()  # leave no test secret behind
    assert RedactSecrets().redact("GET /api/v1/cameras?limit=5") == "GET /api/v1/cameras?limit=5"
