"""Located targets: their latest positions, their tracks, and the live stream over WebSocket."""

from __future__ import annotations

import asyncio
from typing import Annotated, Literal

from fastapi import APIRouter, Path, Query, WebSocket, WebSocketDisconnect, status
from sqlalchemy import select
from starlette.concurrency import run_in_threadpool

from server.api._crud import get_or_404, paginate
from server.api.deps import PageDep, ReadAccess, SessionDep
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Target, TrackPoint
from server.schemas.common import MAX_ID, Page
from server.schemas.localization import TargetRead, Track
from server.services.auth import authenticate

router = APIRouter(tags=["localization"], responses=PROBLEM_RESPONSES)
TargetId = Annotated[int, Path(ge=1, le=MAX_ID)]
# The stream's fastest rate (messages per second).
_STREAM_HZ = 10.0


@router.get("/targets", response_model=Page[TargetRead], dependencies=[ReadAccess])
def list_targets(
    session: SessionDep,
    page: PageDep,
    kind: Annotated[Literal["robot", "person", "external"] | None, Query()] = None,
):
    """Return a page of targets with their latest position, optionally of one kind."""
    stmt = select(Target).order_by(Target.id)
    if kind is not None:
        stmt = stmt.where(Target.kind == kind)
    return paginate(session, stmt, page)


@router.get("/targets/{target_id}", response_model=TargetRead, dependencies=[ReadAccess])
def get_target(target_id: TargetId, session: SessionDep):
    """Return one target."""
    return get_or_404(session, Target, target_id, "target")


@router.get("/targets/{target_id}/track", response_model=Track, dependencies=[ReadAccess])
def get_track(
    target_id: TargetId,
    session: SessionDep,
    since: Annotated[float | None, Query(allow_inf_nan=False, description="Seconds.")] = None,
    limit: Annotated[int, Query(ge=1, le=10_000)] = 1000,
):
    """Return the target's track points (t, xy, cov), oldest first: the newest `limit` points
    at or after `since`."""
    get_or_404(session, Target, target_id, "target")
    stmt = select(TrackPoint).where(TrackPoint.target_id == target_id)
    if since is not None:
        stmt = stmt.where(TrackPoint.t >= since)
    rows = session.scalars(stmt.order_by(TrackPoint.id.desc()).limit(limit)).all()
    points = [{"t": p.t, "xy": [p.x, p.y], "cov": p.cov} for p in reversed(rows)]
    return {"target_id": target_id, "points": points}


def _token_ok(websocket: WebSocket, token: str | None) -> bool:
    state = websocket.app.state
    settings = state.settings
    if token is None:
        return settings.public_reads
    principal = state.token_cache.get(token)
    if principal is None:
        configured = settings.admin_token.get_secret_value() if settings.admin_token else None
        with state.session_factory() as session:
            principal = authenticate(session, token, configured)
        if principal is None:
            return False
        state.token_cache.put(token, principal)
    return principal.can("read")


@router.websocket("/ws/targets")
async def stream_targets(websocket: WebSocket, token: str | None = None) -> None:
    """Stream {"type": "positions", "t", "targets": [{id, label, kind, xy, cov}]} whenever a
    position changes, at most 10 times a second. Authenticate with ?token=<read token>; a bad
    token closes the socket with code 1008."""
    await websocket.accept()
    if not await run_in_threadpool(_token_ok, websocket, token):
        await websocket.close(code=status.WS_1008_POLICY_VIOLATION, reason="bad or missing token")
        return
    live = websocket.app.state.targets
    seen = -1
    loop = asyncio.get_running_loop()
    try:
        while True:
            version, items = live.snapshot()
            if version != seen:
                seen = version
                await websocket.send_json(
                    {
                        "type": "positions",
                        "t": max((i["t"] for i in items), default=None),
                        "targets": [
                            {k: i[k] for k in ("id", "label", "kind", "xy", "cov")} for i in items
                        ],
                    }
                )
            start = loop.time()
            try:
                # A client message (or its leaving) is noticed while waiting for the next tick.
                await asyncio.wait_for(websocket.receive_text(), timeout=1.0 / _STREAM_HZ)
            except TimeoutError:
                pass
            remaining = 1.0 / _STREAM_HZ - (loop.time() - start)
            if remaining > 0:
                await asyncio.sleep(remaining)
    except WebSocketDisconnect:
        return
