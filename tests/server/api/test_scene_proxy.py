"""The live 3D scene behind the API's credentials: viser bound to loopback only, its page and
WebSocket proxied under /api/v1/scene/view, nothing of it without a read credential, and no
viewer may ask it to be published through viser's share service."""

from __future__ import annotations

import asyncio
import contextlib
import shutil
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
import viser
import zstandard
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from server.app import create_app
from server.scene import SceneService
from tests.support.ports import free_port
from tests.support.service import start_service

VISER_PROTOCOL = f"viser-v{viser.__version__}"


@pytest.fixture
def database_url(tmp_path: Path, sqlite_template: Path) -> str:
    """The proxy does not depend on the database backend: SQLite only."""
    path = tmp_path / "intspace.sqlite3"
    shutil.copyfile(sqlite_template, path)
    return f"sqlite:///{path}"


def listening_addresses(port: int) -> set[str]:
    """Return the local addresses (hex, as the kernel lists them) listening on TCP `port`."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        path = Path(table)
        if not path.is_file():
            continue
        for line in path.read_text().splitlines()[1:]:
            fields = line.split()
            address, hex_port = fields[1].split(":")
            if int(hex_port, 16) == port and fields[3] == "0A":  # 0A: LISTEN
                found.add(address)
    return found


def messages(raw: bytes) -> list[dict]:
    """Decode one viser WebSocket frame: two little-endian sizes, zstd msgpack, raw buffers."""
    size = int.from_bytes(raw[0:8], "little")
    compressed = int.from_bytes(raw[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(raw[16 : 16 + compressed], max_output_size=size)
    return msgspec.msgpack.decode(inner)["messages"]


@pytest.fixture
def scene_client(make_settings) -> Iterator[tuple[TestClient, int]]:
    port = free_port()
    settings = make_settings(viser_enabled=True, viser_port=port)
    with TestClient(create_app(settings)) as client:
        yield client, client.app.state.runtime.viser_port


def test_viser_listens_on_loopback_only(scene_client):
    _, port = scene_client
    # 0100007F is 127.0.0.1 in the kernel's byte order; no wildcard (00000000, ::) listener.
    assert listening_addresses(port) == {"0100007F"}


def test_no_byte_of_the_scene_without_a_read_credential(scene_client, admin):
    client, _ = scene_client
    for path in ("/api/v1/scene/view/", "/api/v1/scene/view/index.html"):
        response = client.get(path)
        assert response.status_code == 401
        assert "viser" not in response.text.lower()
        assert response.headers["content-type"].startswith("application/problem+json")
    for kwargs in ({}, {"headers": {"authorization": "Bearer wrong-token-0123456789"}}):
        with pytest.raises(WebSocketDisconnect) as refused:  # refused at the handshake
            with client.websocket_connect(
                "/api/v1/scene/view", subprotocols=[VISER_PROTOCOL], **kwargs
            ):
                pass
        assert refused.value.code == 1008
    # An ingest token (a camera node's) does not read the scene either.
    node = client.post("/api/v1/tokens", json={"name": "node", "scopes": ["ingest"]}, headers=admin)
    bearer = {"Authorization": f"Bearer {node.json()['token']}"}
    assert client.get("/api/v1/scene/view/", headers=bearer).status_code == 403


def test_with_a_read_credential_the_page_and_the_scene_come_through(scene_client, admin):
    client, port = scene_client
    camera = client.post(
        "/api/v1/cameras", json={"name": "door", "width": 640, "height": 480}, headers=admin
    ).json()
    response = client.get("/api/v1/scene/view/", headers=admin)
    assert response.status_code == 200 and "text/html" in response.headers["content-type"]
    # The same page viser serves on its own port, byte for byte.
    import urllib.request

    with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10) as direct:
        assert response.content == direct.read()

    def replay() -> set[str]:
        """Return the scene nodes a viewer is sent through the proxy, up to the replay's end."""
        names: set[str] = set()
        with client.websocket_connect(
            "/api/v1/scene/view", subprotocols=[VISER_PROTOCOL], headers=admin
        ) as ws:
            assert ws.accepted_subprotocol == VISER_PROTOCOL
            while True:
                for m in messages(ws.receive_bytes()):
                    if m["type"] == "ReplayDoneMessage":
                        return names
                    if m.get("name"):
                        names.add(m["name"])

    # The camera is drawn by the scene's worker within moments of its creation.
    deadline = time.monotonic() + 5
    while f"/cameras/{camera['id']}/frustum" not in (names := replay()):
        assert time.monotonic() < deadline, f"the camera never reached the scene: {names}"
        time.sleep(0.1)
    # A dashboard session reads it too, from the service's own origin.
    client.post("/api/v1/session", json={"token": admin["Authorization"][7:]})
    cookie = f"intspace_session={client.cookies['intspace_session']}"
    with client.websocket_connect(
        "/api/v1/scene/view",
        subprotocols=[VISER_PROTOCOL],
        headers={"cookie": cookie, "origin": "http://testserver"},
    ) as ws:
        assert messages(ws.receive_bytes())
    with pytest.raises(WebSocketDisconnect):
        with client.websocket_connect(
            "/api/v1/scene/view",
            subprotocols=[VISER_PROTOCOL],
            headers={"cookie": cookie, "origin": "http://evil.example"},
        ):
            pass


def test_a_viewer_cannot_ask_for_a_share_url():
    from websockets.sync.client import connect

    scene = SceneService("127.0.0.1", free_port())
    scene.start()
    try:
        server = scene.server
        with connect(f"ws://127.0.0.1:{scene.port}", subprotocols=[VISER_PROTOCOL]) as ws:
            ws.send(msgspec.msgpack.encode({"type": "ShareUrlRequest"}))
            deadline = time.monotonic() + 5
            while scene.share_requests_refused == 0 and time.monotonic() < deadline:
                time.sleep(0.02)
        assert scene.share_requests_refused == 1
        assert server._share_tunnel is None  # no tunnel to the share service was opened
        with pytest.raises(PermissionError):
            server.request_share_url()
    finally:
        scene.stop()


def test_a_viewer_that_goes_away_leaves_no_traceback_in_the_service_log(repo_root, tmp_path):
    """The service started as a user starts it; viewers of the proxied scene leave in each way a
    browser can: closing the WebSocket, dropping the connection (a tab killed, a laptop lid
    shut) before or after the first message, and staying while the service stops."""
    token = "scene-proxy-test-admin-token"
    env = {"INTSPACE_SIMULATION": "false", "INTSPACE_VISER_ENABLED": "true"}
    service = start_service(tmp_path, token=token, env=env, wait=False)
    process = service.process
    url = f"ws://127.0.0.1:{service.port}/api/v1/scene/view"
    headers = {"Authorization": f"Bearer {token}"}

    async def viewers() -> list[str]:
        left = []
        for how in ("close", "drop", "drop before the first message"):
            ws = await connect(
                url, additional_headers=headers, subprotocols=[VISER_PROTOCOL], max_size=None
            )
            if how != "drop before the first message":
                assert messages(await ws.recv())  # the scene came through the proxy
            if how == "close":
                await ws.close()
            else:
                ws.transport.abort()  # no closing handshake: the TCP connection just ends
            left.append(how)
            # The relay notices and ends. Time must pass: its end shows nowhere outside the
            # service (no log line, nothing the API answers) but in a traceback, read at the end.
            await asyncio.sleep(0.5)
        # The last viewer stays while the service stops (Ctrl-C): its relay is cancelled.
        ws = await connect(
            url, additional_headers=headers, subprotocols=[VISER_PROTOCOL], max_size=None
        )
        assert messages(await ws.recv())
        process.send_signal(signal.SIGINT)
        with contextlib.suppress(ConnectionClosed):
            async for _ in ws:
                pass
        left.append("stayed to the end")
        return left

    try:
        service.wait_healthy()
        assert len(asyncio.run(viewers())) == 4
        assert process.wait(timeout=20) == 0
    finally:
        service.stop()
    log = service.log()
    # Each viewer was relayed (uvicorn logs the accepted handshakes), and none left a trace.
    assert log.count('"WebSocket /api/v1/scene/view" [accepted]') == 4, log
    assert "Traceback" not in log and "Exception in ASGI application" not in log, log
    assert "ERROR" not in log, log
