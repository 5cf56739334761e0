"""The dashboard's sign-in: a token posted once becomes an HttpOnly SameSite=Strict session
cookie, so the page never holds a token and no token travels in a URL.

POST /session {"token"} signs in (read, write or admin tokens; not ingest), GET /session says
who is calling and gives the session's CSRF token, DELETE /session signs out.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Depends, HTTPException, Request, Response, status
from fastapi.security import HTTPAuthorizationCredentials
from starlette.concurrency import run_in_threadpool

from server.api.deps import (
    SESSION_COOKIE,
    AuthLimiterDep,
    AuthRefused,
    SessionFactoryDep,
    SettingsDep,
    TokenCacheDep,
    bearer_scheme,
    caller,
    check_csrf,
    clear_cookie_header,
    client_key,
    cookie_scheme,
    principal_of,
    same_origin,
)
from server.api.errors import PROBLEM_RESPONSES
from server.schemas.tokens import SessionLogin, SessionState
from server.services.auth import (
    KIND_SESSION,
    Principal,
    create_session,
    csrf_token,
    end_session,
)

router = APIRouter(prefix="/session", tags=["session"], responses=PROBLEM_RESPONSES)


def _state(
    principal: Principal | None,
    via: Literal["cookie", "bearer"] | None,
    session_token: str | None,
    public: bool,
) -> SessionState:
    if principal is None:
        return SessionState(authenticated=False, public_reads=public)
    return SessionState(
        authenticated=True,
        via=via,
        name=principal.name,
        scopes=principal.scopes,
        camera_ids=None if principal.camera_ids is None else sorted(principal.camera_ids),
        expires_at=principal.expires_at,
        csrf_token=None if session_token is None else csrf_token(session_token),
        public_reads=public,
    )


@router.get("", response_model=SessionState)
async def who_am_i(
    request: Request,
    response: Response,
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)],
    session_token: Annotated[str | None, Depends(cookie_scheme)],
) -> SessionState:
    """Return who is calling (authenticated or not: never a 401 for an ended session, whose
    cookie is removed) and, for a dashboard session, the CSRF token its writes send as
    X-CSRF-Token."""
    try:
        principal, via_cookie = await caller(request, settings, credentials, session_token)
    except AuthRefused as refused:
        if session_token and credentials is None and refused.status_code == 401:
            response.headers["Set-Cookie"] = refused.headers["Set-Cookie"]
            return _state(None, None, None, settings.public_reads)
        raise refused.http() from None
    via: Literal["cookie", "bearer"] | None = None
    if principal is not None:
        via = "cookie" if via_cookie else "bearer"
    return _state(principal, via, via_cookie, settings.public_reads)


@router.post("", response_model=SessionState)
async def sign_in(
    body: SessionLogin,
    request: Request,
    response: Response,
    settings: SettingsDep,
    limiter: AuthLimiterDep,
    factory: SessionFactoryDep,
) -> SessionState:
    """Sign in to the dashboard with a read, write or admin token: the answer sets the
    HttpOnly SameSite=Strict session cookie (valid INTSPACE_SESSION_TTL_S seconds) and gives the
    CSRF token. Repeated failures from one client are answered 429 with Retry-After."""
    origin = request.headers.get("origin")
    if origin is not None and not same_origin(request, origin, settings):
        raise HTTPException(status.HTTP_403_FORBIDDEN, f"sign-in from {origin} is not allowed")
    key = client_key(request)
    wait = limiter.retry_after(key)
    if wait is not None:
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            f"too many failed sign-ins from this client; try again in {wait} s",
            headers={"Retry-After": str(wait)},
        )
    principal = await principal_of(request, body.token)
    if principal is None or principal.kind == KIND_SESSION:
        limiter.failed(key)
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "the token is unknown or revoked")
    if not principal.can("read"):
        raise HTTPException(
            status.HTTP_403_FORBIDDEN,
            "an ingest token is a camera node's; sign in with a read, write or admin token",
        )

    def make() -> tuple[float | None, str]:
        with factory() as session:
            row, token = create_session(session, principal, settings.session_ttl_s)
            return row.expires_at, token

    expires_at, token = await run_in_threadpool(make)
    response.set_cookie(
        SESSION_COOKIE,
        token,
        max_age=int(settings.session_ttl_s),
        path="/",
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
    response.headers["Cache-Control"] = "no-store"
    signed_in = Principal(
        token_id=None,
        name=f"browser session of {principal.name}",
        rights=principal.rights,
        kind=KIND_SESSION,
        expires_at=expires_at,
    )
    return _state(signed_in, "cookie", token, settings.public_reads)


@router.delete("", status_code=status.HTTP_204_NO_CONTENT)
async def sign_out(
    request: Request,
    settings: SettingsDep,
    session_token: Annotated[str | None, Depends(cookie_scheme)],
    factory: SessionFactoryDep,
    tokens: TokenCacheDep,
) -> Response:
    """Sign out: the session ends at once (on every API process) and its cookie is removed.
    Needs the session's X-CSRF-Token; an ended session just loses its cookie."""
    secure = request.url.scheme == "https"
    if session_token:
        principal = await principal_of(request, session_token)
        if principal is not None and principal.kind == KIND_SESSION:
            try:
                check_csrf(request, settings, session_token)
            except AuthRefused as refused:
                raise refused.http() from None

            def end() -> None:
                with factory() as session:
                    end_session(session, session_token)

            await run_in_threadpool(end)
            tokens.clear()
    return Response(
        status_code=status.HTTP_204_NO_CONTENT,
        headers={"Set-Cookie": clear_cookie_header(secure), "Cache-Control": "no-store"},
    )
