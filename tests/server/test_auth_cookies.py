"""Credentials of the service against the real app and database: the dashboard's HttpOnly
SameSite=Strict session cookie with its CSRF token, scoped bearer tokens (read, write, admin,
and a camera node's ingest token bound to its cameras), WebSockets authenticated without a URL
token, and failed authentication slowed per client."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from server.app import create_app
from server.cli import main

ORIGIN = "http://testserver"  # TestClient's own origin


def sign_in(client: TestClient, token: str) -> dict:
    response = client.post("/api/v1/session", json={"token": token})
    assert response.status_code == 200, response.text
    return response.json()


def new_token(client: TestClient, admin: dict, scopes: list[str], **extra) -> dict:
    body = {"name": f"{'-'.join(scopes)} token", "scopes": scopes, **extra}
    response = client.post("/api/v1/tokens", json=body, headers=admin)
    assert response.status_code == 201, response.text
    return response.json()


def test_sign_in_sets_an_httponly_strict_cookie_holding_no_token(client, admin):
    response = client.post("/api/v1/session", json={"token": admin["Authorization"][7:]})
    assert response.status_code == 200, response.text
    cookie = response.headers["set-cookie"]
    assert cookie.startswith("intspace_session=iss_")
    flags = {f.strip().lower() for f in cookie.split(";")[1:]}
    assert {"httponly", "samesite=strict", "path=/"} <= flags
    assert admin["Authorization"][7:] not in cookie  # a session of its own, not the token
    body = response.json()
    assert body["authenticated"] and body["via"] == "cookie" and body["scopes"] == ["admin"]
    assert len(body["csrf_token"]) == 64

    # The cookie alone reads; GET /session gives the same CSRF token back after a reload.
    assert client.get("/api/v1/cameras").status_code == 200
    again = client.get("/api/v1/session").json()
    assert again["csrf_token"] == body["csrf_token"] and again["via"] == "cookie"
    # Sessions are not API tokens: the admin's token list does not show them.
    tokens = client.get("/api/v1/tokens", headers=admin).json()
    assert all(not t["name"].startswith("browser session") for t in tokens["items"])


def test_writes_through_the_cookie_need_the_csrf_token_and_the_own_origin(client, admin):
    csrf = sign_in(client, admin["Authorization"][7:])["csrf_token"]
    space = {"name": "flat", "description": ""}
    assert client.post("/api/v1/spaces", json=space).status_code == 403
    wrong = {"X-CSRF-Token": "0" * 64}
    assert client.post("/api/v1/spaces", json=space, headers=wrong).status_code == 403
    foreign = {"X-CSRF-Token": csrf, "Origin": "http://evil.example"}
    response = client.post("/api/v1/spaces", json=space, headers=foreign)
    assert response.status_code == 403 and "evil.example" in response.json()["detail"]
    ok = {"X-CSRF-Token": csrf, "Origin": ORIGIN}
    assert client.post("/api/v1/spaces", json=space, headers=ok).status_code == 201
    # A bearer token needs no CSRF token (no browser sends it on its own).
    client.cookies.clear()
    other = {**space, "name": "another flat"}  # space names are unique
    assert client.post("/api/v1/spaces", json=other, headers=admin).status_code == 201


def test_sign_out_and_revocation_end_sessions(client, admin):
    read = new_token(client, admin, ["read"])
    state = sign_in(client, read["token"])
    assert state["scopes"] == ["read"]
    cookie = client.cookies["intspace_session"]
    headers = {"X-CSRF-Token": state["csrf_token"]}
    # A read sign-in cannot write, CSRF token or not.
    response = client.post("/api/v1/spaces", json={"name": "x"}, headers=headers)
    assert response.status_code == 403
    # The session's token is a cookie's value, not a bearer token.
    as_bearer = {"Authorization": f"Bearer {cookie}"}
    (domain,) = {c.domain for c in client.cookies.jar}
    client.cookies.clear()
    assert client.get("/api/v1/cameras", headers=as_bearer).status_code == 401
    client.cookies.set("intspace_session", cookie, domain=domain)

    # Revoking the token it signed in with ends the session at once.
    client.delete(f"/api/v1/tokens/{read['id']}", headers=admin)
    response = client.get("/api/v1/cameras")
    assert response.status_code == 401
    assert "intspace_session=;" in response.headers["set-cookie"]  # the stale cookie goes
    assert client.get("/api/v1/session").json()["authenticated"] is False

    # Sign-out needs the CSRF token, then the old cookie value is dead everywhere.
    state = sign_in(client, admin["Authorization"][7:])
    cookie = client.cookies["intspace_session"]
    assert client.delete("/api/v1/session").status_code == 403
    response = client.delete("/api/v1/session", headers={"X-CSRF-Token": state["csrf_token"]})
    assert response.status_code == 204 and "Max-Age=0" in response.headers["set-cookie"]
    client.cookies.set("intspace_session", cookie, domain=domain)  # kept by a client
    assert client.get("/api/v1/cameras").status_code == 401


def test_ingest_tokens_post_for_their_cameras_and_nothing_else(client, admin):
    cams = [
        client.post(
            "/api/v1/cameras", json={"name": n, "width": 640, "height": 480}, headers=admin
        ).json()["id"]
        for n in ("door", "hall")
    ]
    mine, other = cams
    node = new_token(client, admin, ["ingest"], camera_ids=[mine])
    assert node["camera_ids"] == [mine]
    bearer = {"Authorization": f"Bearer {node['token']}"}
    beat = {"fps": 5.0}
    assert client.post(f"/api/v1/cameras/{mine}/heartbeat", json=beat, headers=bearer).is_success
    assert client.get(f"/api/v1/cameras/{mine}", headers=bearer).status_code == 200
    for method, path, body in [
        ("POST", f"/api/v1/cameras/{other}/heartbeat", beat),
        ("GET", f"/api/v1/cameras/{other}", None),
        ("GET", "/api/v1/cameras", None),
        ("GET", "/api/v1/targets", None),
        ("POST", "/api/v1/spaces", {"name": "x"}),
        ("PATCH", f"/api/v1/cameras/{mine}", {"name": "renamed"}),
        ("GET", "/api/v1/tokens", None),
    ]:
        response = client.request(method, path, json=body, headers=bearer)
        assert response.status_code == 403, (method, path, response.text)
    # Observations are refused for a camera the token does not speak for, before validation;
    # for its own (uncalibrated) camera they reach the endpoint, which names what is missing.
    obs = {"t": 1.0, "pixel": [320.0, 240.0]}
    foreign = {"observations": [{**obs, "camera_id": mine}, {**obs, "camera_id": other}]}
    response = client.post("/api/v1/observations", json=foreign, headers=bearer)
    assert response.status_code == 403 and str(other) in response.json()["detail"]
    own = {"observations": [{**obs, "camera_id": mine}]}
    assert client.post("/api/v1/observations", json=own, headers=bearer).status_code == 422
    # An ingest token signs no one in to the dashboard; camera_ids bind ingest tokens only.
    assert client.post("/api/v1/session", json={"token": node["token"]}).status_code == 403
    response = client.post(
        "/api/v1/tokens",
        json={"name": "bad", "scopes": ["read"], "camera_ids": [mine]},
        headers=admin,
    )
    assert response.status_code == 422


def test_websockets_take_a_header_a_subprotocol_or_the_cookie_never_a_url(client, admin):
    token = admin["Authorization"][7:]
    with client.websocket_connect("/api/v1/ws/targets", headers=admin) as ws:
        assert ws.receive_json()["type"] == "positions"
    with client.websocket_connect(
        "/api/v1/ws/targets", subprotocols=["intspace", f"bearer.{token}"]
    ) as ws:
        assert ws.accepted_subprotocol == "intspace"  # the token is never echoed
        assert ws.receive_json()["type"] == "positions"

    def refused(path: str, **kwargs) -> tuple[int, str]:
        with (
            client.websocket_connect(path, **kwargs) as ws,
            pytest.raises(WebSocketDisconnect) as exc,
        ):
            ws.receive_json()
        return exc.value.code, exc.value.reason

    code, reason = refused(f"/api/v1/ws/targets?token={token}")
    assert code == 1008 and "URL" in reason
    assert refused("/api/v1/ws/targets")[0] == 1008
    assert refused("/api/v1/ws/targets", subprotocols=["intspace", "bearer.wrong"])[0] == 1008

    sign_in(client, token)
    cookie = {"cookie": f"intspace_session={client.cookies['intspace_session']}"}
    with client.websocket_connect("/api/v1/ws/targets", headers={**cookie, "origin": ORIGIN}) as ws:
        assert ws.receive_json()["type"] == "positions"
    # Another site's page cannot ride the browser's cookie (cross-site WebSocket hijacking).
    code, reason = refused(
        "/api/v1/ws/targets", headers={**cookie, "origin": "http://evil.example"}
    )
    assert code == 1008 and "evil.example" in reason


def test_repeated_failed_authentication_is_slowed_down(make_settings):
    with TestClient(create_app(make_settings(auth_failure_limit="3/minute"))) as client:
        wrong = {"Authorization": "Bearer not-a-token"}
        assert [client.get("/api/v1/cameras", headers=wrong).status_code for _ in range(2)] == [
            401,
            401,
        ]
        assert client.post("/api/v1/session", json={"token": "guess"}).status_code == 401
        response = client.get("/api/v1/cameras", headers=wrong)
        assert response.status_code == 429
        # A moving one-minute window: the client may try again within the minute.
        assert 1 <= int(response.headers["retry-after"]) <= 60
        # While slowed down, even the right token waits (a guesser cannot tell a hit).
        right = {"Authorization": "Bearer test-admin-token"}
        assert client.get("/api/v1/cameras", headers=right).status_code == 429
        assert client.post("/api/v1/session", json={"token": "test-admin-token"}).status_code == 429


def test_a_short_admin_token_is_refused_at_start(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("INTSPACE_ADMIN_TOKEN", "short-token")
    monkeypatch.setenv("INTSPACE_DATA_DIR", str(tmp_path))
    monkeypatch.chdir(tmp_path)  # no .env of the developer's
    assert main(["serve", "--port", "1"]) == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "at least 16" in lines[0] and "11 characters" in lines[0]
    assert "short-token" not in out + err
    assert not (tmp_path / "intspace.sqlite3").exists()  # refused before touching anything
