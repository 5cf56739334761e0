"""Located targets: their latest positions, their tracks, and the live stream over WebSocket."""

from __future__ import annotations

import asyncio
import json
import time
import weakref
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Path, Query, WebSocket, WebSocketDisconnect, status
from sqlalchemy import select

from server.api._crud import get_or_404, paginate
from server.api.deps import (
    AuthRefused,
    LiveTargetsDep,
    PageDep,
    ReadAccess,
    SessionDep,
    websocket_caller,
)
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Target, TrackPoint
from server.schemas.common import MAX_ID, Page
from server.schemas.localization import TargetRead, Track, TrackSet
from server.services.targets import LIVE

router = APIRouter(tags=["localization"], responses=PROBLEM_RESPONSES)
TargetId = Annotated[int, Path(ge=1, le=MAX_ID)]
SpaceFilter = Annotated[
    int | None, Query(ge=1, le=MAX_ID, description="Only the targets of this space.")
]
# The stream's fastest rate (messages per second): a change waits at most 1 / _STREAM_HZ s for
# the previous message's slot, yet a tracker updating on every camera frame (ten cameras at
# 10 Hz) does not send a browser a hundred messages a second.
_STREAM_HZ = 30.0
# What the stream says of each target.
_TARGET_KEYS = ("id", "label", "kind", "state", "t", "xy", "cov")


@router.get("/targets", response_model=Page[TargetRead], dependencies=[ReadAccess])
def list_targets(
    session: SessionDep,
    page: PageDep,
    kind: Annotated[Literal["robot", "person", "unknown"] | None, Query()] = None,
    state: Annotated[
        Literal["live", "all"],
        Query(description="live: confirmed and coasting targets; all: ended ones too."),
    ] = "live",
    space_id: SpaceFilter = None,
):
    """Return a page of targets with their latest position and life cycle state, newest
    first (by last update): the live ones, or all with state=all; optionally of one kind or
    one space."""
    stmt = select(Target).order_by(Target.last_seen.desc().nulls_last(), Target.id.desc())
    if state == "live":
        stmt = stmt.where(Target.state.in_(LIVE))
    if kind is not None:
        stmt = stmt.where(Target.kind == kind)
    if space_id is not None:
        stmt = stmt.where(Target.space_id == space_id)
    return paginate(session, stmt, page)


@router.get("/targets/tracks", response_model=TrackSet, dependencies=[ReadAccess])
def list_tracks(
    session: SessionDep,
    state: Annotated[Literal["live", "all"], Query()] = "live",
    since: Annotated[
        float | None, Query(allow_inf_nan=False, description="Unix seconds; default: 60 s ago.")
    ] = None,
    points: Annotated[int, Query(ge=1, le=2000, description="Newest points per target.")] = 400,
    targets: Annotated[int, Query(ge=1, le=200, description="Newest targets.")] = 50,
    space_id: SpaceFilter = None,
):
    """Return the recent track of each of the newest targets (live, or all; of one space or
    every one) in one answer: the newest `points` points at or after `since`, oldest first, so
    a page draws where everyone went without a request per target."""
    since = time.time() - 60.0 if since is None else since
    stmt = select(Target).where(Target.last_seen >= since)
    if state == "live":
        stmt = stmt.where(Target.state.in_(LIVE))
    if space_id is not None:
        stmt = stmt.where(Target.space_id == space_id)
    rows = session.scalars(
        stmt.order_by(Target.last_seen.desc().nulls_last(), Target.id.desc()).limit(targets)
    ).all()
    out = []
    for row in rows:
        pts = session.execute(
            select(TrackPoint.t, TrackPoint.x, TrackPoint.y)
            .where(TrackPoint.target_id == row.id, TrackPoint.t >= since)
            .order_by(TrackPoint.t.desc())
            .limit(points)
        ).all()
        out.append(
            {
                "target_id": row.id,
                "label": row.label,
                "kind": row.kind,
                "state": row.state,
                "points": [[t, x, y] for t, x, y in reversed(pts)],
            }
        )
    return {"since": since, "tracks": out}


@router.get("/targets/{target_id}", response_model=TargetRead, dependencies=[ReadAccess])
def get_target(target_id: TargetId, session: SessionDep):
    """Return one target."""
    return get_or_404(session, Target, target_id, "target")


@router.get("/targets/{target_id}/track", response_model=Track, dependencies=[ReadAccess])
def get_track(
    target_id: TargetId,
    session: SessionDep,
    since: Annotated[float | None, Query(allow_inf_nan=False, description="Seconds.")] = None,
    until: Annotated[
        float | None,
        Query(
            allow_inf_nan=False,
            description="Seconds: only points before this time, to page back from the oldest "
            "point of the previous page.",
        ),
    ] = None,
    limit: Annotated[int, Query(ge=1, le=10_000)] = 1000,
):
    """Return the target's track points (t, xy, cov), oldest first: the newest `limit` points
    at or after `since` and before `until` (Unix seconds, the observations' own times)."""
    get_or_404(session, Target, target_id, "target")
    stmt = select(TrackPoint).where(TrackPoint.target_id == target_id)
    if since is not None:
        stmt = stmt.where(TrackPoint.t >= since)
    if until is not None:
        stmt = stmt.where(TrackPoint.t < until)
    order = (TrackPoint.t.desc(), TrackPoint.id.desc())
    rows = session.scalars(stmt.order_by(*order).limit(limit)).all()
    points = [{"t": p.t, "xy": [p.x, p.y], "cov": p.cov} for p in reversed(rows)]
    return {"target_id": target_id, "points": points}


@router.websocket("/ws/targets")
async def stream_targets(websocket: WebSocket, live: LiveTargetsDep) -> None:
    """Stream {"type": "positions", "t", "targets": [{id, label, kind, state, t, xy, cov}]}
    of the live targets whenever one changes, at most 30 times a second: each target's `t` is
    the capture time of the observation of its last update, the message's `t` the newest of
    them (Unix seconds on the service's clock). Authenticate with
    `Authorization: Bearer <read token>`, by offering the subprotocols `intspace` and
    `bearer.<read token>` (the answer names only `intspace`), or with the dashboard's session
    cookie from the service's own page; tokens in the URL are refused. A refused credential
    closes the socket with code 1008 and the reason. `?space_id=N` streams only that space's
    targets (a message is still sent when another space's change, with the same targets)."""
    if "token" in websocket.query_params:
        await websocket.accept()
        await websocket.close(
            code=status.WS_1008_POLICY_VIOLATION,
            reason="tokens never travel in URLs: use the Authorization header or "
            "Sec-WebSocket-Protocol",
        )
        return
    try:
        who = await websocket_caller(websocket, "read")
    except AuthRefused as refused:
        await websocket.accept()
        await websocket.close(code=status.WS_1008_POLICY_VIOLATION, reason=refused.detail[:120])
        return
    raw_space = websocket.query_params.get("space_id")
    space_id: int | None = None
    if raw_space is not None:
        if not raw_space.isdigit() or not 1 <= int(raw_space) <= MAX_ID:
            await websocket.accept()
            await websocket.close(
                code=status.WS_1008_POLICY_VIOLATION,
                reason=f"space_id must be an integer from 1 to {MAX_ID}",
            )
            return
        space_id = int(raw_space)
    await websocket.accept(subprotocol=who.subprotocol)
    seen = -1
    loop = asyncio.get_running_loop()
    last_sent = -float("inf")
    changed = asyncio.Event()
    unwatch = live.watch(lambda: _wake(loop, changed))
    receiving = asyncio.ensure_future(websocket.receive_text())
    try:
        while True:
            # A change is sent as soon as the live targets say it happened, but no sooner than
            # 1 / _STREAM_HZ after the previous message: an idle stream answers a new target
            # within milliseconds, a busy one at the stream's rate.
            changed.clear()
            wait: float | None = None  # until a change or a client message
            if live.version != seen:
                wait = max(0.0, last_sent + 1.0 / _STREAM_HZ - loop.time())
                if wait == 0.0:
                    seen, text = _positions_message(live, space_id)
                    last_sent = loop.time()
                    await websocket.send_text(text)
                    continue
            # A client message (or its leaving) is noticed while waiting for the next change.
            waiting = asyncio.ensure_future(changed.wait())
            done, _ = await asyncio.wait(
                {receiving, waiting}, timeout=wait, return_when=asyncio.FIRST_COMPLETED
            )
            waiting.cancel()
            if receiving in done:
                receiving.result()  # raises WebSocketDisconnect when the client left
                receiving = asyncio.ensure_future(websocket.receive_text())
    except WebSocketDisconnect:
        return
    finally:
        unwatch()
        receiving.cancel()


# The last positions message of each live-targets store and space (None: every space), by its
# version: every subscriber of a version sends the same text, encoded once (the streams all run
# on the event loop's thread).
_ENCODED: weakref.WeakKeyDictionary[Any, dict[int | None, tuple[int, str]]] = (
    weakref.WeakKeyDictionary()
)


def _positions_message(live: Any, space_id: int | None = None) -> tuple[int, str]:
    """Return (version, the stream's JSON text) of the live targets now (of one space, or of
    every space when `space_id` is None)."""
    cache = _ENCODED.setdefault(live, {})
    hit = cache.get(space_id)
    if hit is not None and hit[0] == live.version:
        return hit
    version, items = live.snapshot()
    if space_id is not None:
        items = [i for i in items if i["space_id"] == space_id]
    text = json.dumps(
        {
            "type": "positions",
            "t": max((i["t"] for i in items), default=None),
            "targets": [{k: i[k] for k in _TARGET_KEYS} for i in items],
        },
        separators=(",", ":"),
        ensure_ascii=False,
    )
    cache[space_id] = (version, text)
    return version, text


def _wake(loop: asyncio.AbstractEventLoop, event: asyncio.Event) -> None:
    """Set `event` in its event loop, from any thread (the loop may have closed meanwhile)."""
    try:
        loop.call_soon_threadsafe(event.set)
    except RuntimeError:
        pass
