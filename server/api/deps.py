"""Dependencies shared by the routers: settings, database session, caller, pagination."""

from __future__ import annotations

from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, HTTPException, Query, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from server.schemas.common import MAX_ID
from server.services.auth import Principal, TokenCache, authenticate
from server.services.runs import RunExecutor
from server.services.scene_sync import SceneSync
from server.settings import Settings

_bearer = HTTPBearer(
    auto_error=False,
    description="Authorization: Bearer <token>. The first-run admin token is printed by "
    "`intspace serve`; admins create more with POST /api/v1/tokens.",
)


# Dependencies that do no I/O are `async def`: FastAPI runs a sync one in a worker thread, and
# those hops, not the database, dominated the latency of a registry read.


async def get_settings(request: Request) -> Settings:
    """Return the app's settings."""
    return request.app.state.settings


async def get_session(request: Request) -> AsyncIterator[Session]:
    """Yield a database session for one request, closed (rolled back if uncommitted) after.
    Creating a session does no I/O; closing it may, so that happens in a worker thread."""
    session = request.app.state.session_factory()
    try:
        yield session
    finally:
        await run_in_threadpool(session.close)


async def get_scene(request: Request) -> SceneSync:
    """Return the scene synchroniser (a no-op one when the scene is disabled)."""
    return request.app.state.scene_sync


async def get_executor(request: Request) -> RunExecutor | None:
    """Return the in-process run executor, None when external workers execute runs."""
    return request.app.state.executor


SessionDep = Annotated[Session, Depends(get_session)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
SceneDep = Annotated[SceneSync, Depends(get_scene)]


def _unauthorized(detail: str) -> HTTPException:
    return HTTPException(
        status.HTTP_401_UNAUTHORIZED, detail=detail, headers={"WWW-Authenticate": "Bearer"}
    )


async def _caller(
    request: Request,
    credentials: HTTPAuthorizationCredentials | None,
    settings: Settings,
) -> Principal | None:
    if credentials is None or credentials.scheme.lower() != "bearer":
        return None
    configured = settings.admin_token.get_secret_value() if settings.admin_token else None
    tokens: TokenCache = request.app.state.token_cache
    principal = tokens.get(credentials.credentials)
    if principal is None:
        principal = await run_in_threadpool(
            _authenticate, request.app.state.session_factory, credentials.credentials, configured
        )
        if principal is not None:
            tokens.put(credentials.credentials, principal)
    if principal is None:
        raise _unauthorized("the bearer token is unknown or revoked")
    return principal


def _authenticate(factory, token: str, configured: str | None) -> Principal | None:
    with factory() as session:
        return authenticate(session, token, configured)


def _requiring(right: str):
    async def dependency(
        request: Request,
        settings: SettingsDep,
        credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
    ) -> Principal | None:
        principal = await _caller(request, credentials, settings)
        if principal is None:
            if right == "read" and settings.public_reads:
                return None
            raise _unauthorized("this endpoint needs Authorization: Bearer <token>")
        if not principal.can(right):
            raise HTTPException(
                status.HTTP_403_FORBIDDEN, detail=f"the token lacks the '{right}' scope"
            )
        return principal

    dependency.__name__ = f"require_{right}"
    return dependency


require_read = _requiring("read")
require_write = _requiring("write")
require_admin = _requiring("admin")

ReadAccess = Depends(require_read)
WriteAccess = Depends(require_write)
AdminAccess = Depends(require_admin)


@dataclass(frozen=True)
class Pagination:
    """The window of a listing."""

    limit: int
    offset: int


async def get_pagination(
    limit: Annotated[int, Query(ge=1, le=500, description="Items per page.")] = 50,
    offset: Annotated[int, Query(ge=0, le=MAX_ID, description="Items to skip.")] = 0,
) -> Pagination:
    """Return the pagination window asked for."""
    return Pagination(limit=limit, offset=offset)


PageDep = Annotated[Pagination, Depends(get_pagination)]
