"""The live 3D scene behind the API's credentials: viser listens on loopback only, and the
service proxies its page (GET /scene/view/...) and its WebSocket (/scene/view, the address
viser's page derives from its own) to it, refusing a request without a read credential before a
byte of the scene is sent.

A browser reaches it with the dashboard's session cookie (the WebSocket's Origin must be the
service's own); a script with `Authorization: Bearer <read token>`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Awaitable, Callable
from typing import Annotated, Any

import anyio
import httpx
from fastapi import APIRouter, HTTPException, Path, Request, WebSocket, status
from fastapi.responses import Response
from starlette.websockets import WebSocketDisconnect, WebSocketState
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from server.api.deps import AuthRefused, ReadAccess, SceneDep, ViserPortDep, websocket_caller
from server.api.errors import PROBLEM_RESPONSES
from server.services.scene_sync import SceneSync

router = APIRouter(prefix="/scene/view", tags=["scene"], responses=PROBLEM_RESPONSES)

UPSTREAM_HOST = "127.0.0.1"
# Headers of viser's answer passed on to the browser; the rest (its server name, connection
# handling) stays between the two processes.
_PASSED = ("content-type", "content-encoding", "content-length", "last-modified", "etag")
# How long closing both sides of a relay may take when the relay ends (s).
CLOSE_TIMEOUT_S = 5.0


def _viser_port(scene: SceneSync, port: int) -> int:
    """Return viser's loopback port, refusing with 404 when no scene runs in this process."""
    if scene.scene is None:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            "the 3D scene does not run in this process (INTSPACE_VISER_ENABLED=false, or another "
            "process owns it)",
        )
    return port


@router.get("/", dependencies=[ReadAccess], include_in_schema=False)
async def scene_index(request: Request, scene: SceneDep, port: ViserPortDep) -> Response:
    """Return the viser viewer's page."""
    return await _fetch(request, _viser_port(scene, port), "")


@router.get("/{path:path}", dependencies=[ReadAccess], include_in_schema=False)
async def scene_file(
    request: Request,
    path: Annotated[str, Path(max_length=512)],
    scene: SceneDep,
    port: ViserPortDep,
) -> Response:
    """Return a file of the viser viewer."""
    return await _fetch(request, _viser_port(scene, port), path)


async def _fetch(request: Request, port: int, path: str) -> Response:
    """Return `path` fetched from the loopback viser server on `port`."""
    headers = {"Accept-Encoding": request.headers.get("accept-encoding", "identity")}
    url = httpx.URL(scheme="http", host=UPSTREAM_HOST, port=port, path="/" + path)
    try:
        async with (
            httpx.AsyncClient(timeout=10.0) as client,
            client.stream("GET", url, headers=headers) as upstream,
        ):
            # Raw: still gzip-encoded when viser compressed it, as its headers say.
            content = b"".join([chunk async for chunk in upstream.aiter_raw()])
    except httpx.HTTPError as exc:
        raise HTTPException(
            status.HTTP_502_BAD_GATEWAY, f"the 3D scene server did not answer: {exc}"
        ) from None
    if upstream.status_code == 404:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"the 3D scene has no file {path!r}")
    passed = {k: v for k, v in upstream.headers.items() if k.lower() in _PASSED}
    passed["Cache-Control"] = "no-store"
    return Response(content, status_code=upstream.status_code, headers=passed)


@router.websocket("")
@router.websocket("/")
async def scene_socket(websocket: WebSocket, scene: SceneDep, port: ViserPortDep) -> None:
    """Relay the viser viewer's WebSocket, after checking the caller may read. A refused
    caller's handshake is answered 403 and never reaches viser."""
    try:
        who = await websocket_caller(websocket, "read", protocols=("viser-v*",))
        port = _viser_port(scene, port)
    except (AuthRefused, HTTPException):
        await websocket.close(code=status.WS_1008_POLICY_VIOLATION)
        return
    subprotocols = [who.subprotocol] if who.subprotocol else None
    try:
        upstream = await connect(
            f"ws://{UPSTREAM_HOST}:{port}",
            subprotocols=subprotocols,  # type: ignore[arg-type]
            max_size=None,
            compression=None,
            open_timeout=10,
        )
    except (OSError, InvalidHandshake, TimeoutError):
        await websocket.close(code=status.WS_1011_INTERNAL_ERROR)
        return
    await websocket.accept(subprotocol=who.subprotocol)
    # Either side may leave at any time (a browser closing its tab, viser stopping): the relay
    # then ends quietly, closing the other side; a client that goes away is no error. The two
    # directions run in one anyio task group, so that a cancellation of this handler (the
    # service stopping, the connection's scope ending) reaches them as that same cancellation
    # and ends the handler as cancelled by its scope. (asyncio tasks cancelled here and then
    # gathered turned it into a CancelledError of their own, which escaped the scope that
    # cancelled the handler: the connection's owner saw its handler die of an error.)
    try:
        async with anyio.create_task_group() as relay:
            relay.start_soon(_one_way, _to_viser, websocket, upstream, relay.cancel_scope)
            relay.start_soon(_one_way, _to_browser, upstream, websocket, relay.cancel_scope)
    finally:
        # Closed even when cancelled, within a bounded time.
        with anyio.move_on_after(CLOSE_TIMEOUT_S, shield=True):
            with contextlib.suppress(ConnectionClosed, OSError):
                await upstream.close()
            if websocket.application_state == WebSocketState.CONNECTED:
                # Starlette's WebSocketDisconnect for a browser already gone (uvicorn's
                # ClientDisconnected, an OSError, beneath it); RuntimeError once closed.
                with contextlib.suppress(WebSocketDisconnect, OSError, RuntimeError):
                    await websocket.close()


async def _one_way(
    relay: Callable[[Any, Any], Awaitable[None]],
    source: Any,
    sink: Any,
    both: anyio.CancelScope,
) -> None:
    """Run one direction of the relay; when it ends, end the other one too."""
    try:
        await relay(source, sink)
    finally:
        both.cancel()


async def _to_viser(websocket: WebSocket, upstream: ClientConnection) -> None:
    """Pass the browser's messages to viser until either side closes."""
    with contextlib.suppress(WebSocketDisconnect, ConnectionClosed, OSError, RuntimeError):
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                return
            if message.get("bytes") is not None:
                await upstream.send(message["bytes"])
            elif message.get("text") is not None:
                await upstream.send(message["text"])


async def _to_browser(upstream: ClientConnection, websocket: WebSocket) -> None:
    """Pass viser's messages to the browser until either side closes."""
    with contextlib.suppress(WebSocketDisconnect, ConnectionClosed, OSError, RuntimeError):
        async for data in upstream:
            if isinstance(data, bytes):
                await websocket.send_bytes(data)
            else:
                await websocket.send_text(data)
