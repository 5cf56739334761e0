"""Dependencies shared by the routers: settings, database session, the parts of the service's
runtime (`server.runtime.Runtime`: run executor, 3D scene, digital twin, task runner, tracker,
live targets, zones, ...), caller, pagination. Routes take these, typed; only `runtime_of` reads
the runtime off the app.

Who is calling is read from one of two places, never from a URL:

* `Authorization: Bearer <token>`: scripts and camera nodes (API tokens, the admin token);
* the `intspace_session` cookie (HttpOnly, SameSite=Strict) that POST /session sets when
  someone signs in to the dashboard; a write through it also needs the session's CSRF token in
  the `X-CSRF-Token` header and, when the browser sends one, a same-origin `Origin`.

WebSockets take the same cookie (with its Origin checked), the bearer header, or, for clients
that cannot set headers, a `bearer.<token>` entry in `Sec-WebSocket-Protocol`.
"""

from __future__ import annotations

import hmac
import re
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Annotated, Any, TypeVar

from fastapi import Depends, HTTPException, Query, Request, WebSocket, status
from fastapi.security import APIKeyCookie, HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker
from starlette.concurrency import run_in_threadpool
from starlette.requests import HTTPConnection

from server.runtime import Runtime
from server.schemas.common import MAX_ID
from server.security import AuthFailureLimiter
from server.services.auth import KIND_SESSION, Principal, TokenCache, authenticate, csrf_token
from server.services.camera_health import CameraHealthBook
from server.services.comms.frigate import FrigateSource
from server.services.comms.home import HomePublisher
from server.services.frames import LatestFrames
from server.services.manipulation import TaskRunner
from server.services.path_following import FollowTasks
from server.services.runs import RunExecutor
from server.services.scene_sync import SceneSync
from server.services.targets import LiveTargets
from server.services.tracking import TrackingService
from server.services.twin import Twin
from server.services.zones import ZoneService
from server.settings import Settings

T = TypeVar("T")

SESSION_COOKIE = "intspace_session"
CSRF_HEADER = "X-CSRF-Token"
WS_BEARER_PREFIX = "bearer."
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})

# What a camera node's ingest token may call, and nothing else: (method, path). Each names the
# camera it acts for (in the path, or as every observation's camera_id), which must be one of the
# token's cameras when the token is bound to some.
INGEST_ROUTES = tuple(
    (method, re.compile(pattern))
    for method, pattern in (
        ("POST", r"/api/v1/observations"),
        ("POST", r"/api/v1/cameras/\d+/heartbeat"),
        ("PUT", r"/api/v1/cameras/\d+/frame"),
        ("GET", r"/api/v1/cameras/\d+"),
        ("GET", r"/api/v1/cameras/\d+/stream\.mjpg"),
    )
)

bearer_scheme = HTTPBearer(
    auto_error=False,
    description="Authorization: Bearer <token>. The first-run admin token is printed by "
    "`intspace serve`; admins create more with POST /api/v1/tokens.",
)
cookie_scheme = APIKeyCookie(
    name=SESSION_COOKIE,
    auto_error=False,
    description="The dashboard's sign-in (POST /api/v1/session); writes also need the "
    "X-CSRF-Token header that GET /api/v1/session returns.",
)


# Dependencies that do no I/O are `async def`: FastAPI runs a sync one in a worker thread, and
# those hops, not the database, dominated the latency of a registry read. They take the
# connection (not the request) so that WebSocket routes take them too.


def runtime_of(connection: HTTPConnection) -> Runtime:
    """Return the service's runtime: the one place it is read off the app."""
    runtime: Runtime = connection.app.state.runtime
    return runtime


async def get_settings(connection: HTTPConnection) -> Settings:
    """Return the app's settings."""
    return runtime_of(connection).settings


async def get_engine(connection: HTTPConnection) -> Engine:
    """Return the database engine."""
    return runtime_of(connection).engine


async def get_session_factory(connection: HTTPConnection) -> sessionmaker[Session]:
    """Return the factory of database sessions, for work that outlives the request's session
    (a streamed answer, a thread)."""
    return runtime_of(connection).session_factory


async def get_session(connection: HTTPConnection) -> AsyncIterator[Session]:
    """Yield a database session for one request, closed (rolled back if uncommitted) after.
    Creating a session does no I/O; closing it may, so that happens in a worker thread."""
    session = runtime_of(connection).session_factory()
    try:
        yield session
    finally:
        await run_in_threadpool(session.close)


async def get_scene(connection: HTTPConnection) -> SceneSync:
    """Return the scene synchroniser (a no-op one when the scene is disabled)."""
    return runtime_of(connection).scene_sync


async def get_viser_port(connection: HTTPConnection) -> int:
    """Return the loopback port the 3D scene's viser server listens on."""
    return runtime_of(connection).viser_port


async def get_executor(connection: HTTPConnection) -> RunExecutor | None:
    """Return the in-process run executor, None when external workers execute runs."""
    return runtime_of(connection).executor


async def get_twin(connection: HTTPConnection) -> Twin | None:
    """Return the running digital twin, None without simulation."""
    return runtime_of(connection).twin


def _started(service: T | None, not_started: str) -> T:
    """Return `service`, raising 503 with the message `not_started` while it is None (the app
    has not started it yet)."""
    if service is None:
        raise HTTPException(status.HTTP_503_SERVICE_UNAVAILABLE, not_started)
    return service


async def get_task_runner(connection: HTTPConnection) -> TaskRunner:
    """Return the runner of robot tasks (fetch, survey) started with the app."""
    return _started(runtime_of(connection).task_runner, "the task runner has not started (yet)")


async def get_follow_tasks(connection: HTTPConnection) -> FollowTasks:
    """Return the follow tasks of planned paths run by this process (started with the app)."""
    return _started(
        runtime_of(connection).follow_tasks, "the path follow tasks have not started (yet)"
    )


async def get_latest_frames(connection: HTTPConnection) -> LatestFrames:
    """Return the service's store of uploaded camera frames."""
    return runtime_of(connection).latest_frames


async def get_camera_health(connection: HTTPConnection) -> CameraHealthBook:
    """Return the cameras' health from their nodes' heartbeats."""
    return runtime_of(connection).camera_health


async def get_tracking(connection: HTTPConnection) -> TrackingService | None:
    """Return the trackers' service (None before the app started)."""
    return runtime_of(connection).tracking


async def get_live_targets(connection: HTTPConnection) -> LiveTargets:
    """Return the live targets of every space."""
    return runtime_of(connection).targets


async def get_zones(connection: HTTPConnection) -> ZoneService | None:
    """Return the zones' occupancy service (None before the app started)."""
    return runtime_of(connection).zones


async def get_home(connection: HTTPConnection) -> HomePublisher | None:
    """Return the MQTT publisher to the home, None when no broker is configured."""
    return runtime_of(connection).home


async def get_frigate(connection: HTTPConnection) -> FrigateSource | None:
    """Return Frigate as a source of detections, None when not configured."""
    return runtime_of(connection).frigate


async def get_token_cache(connection: HTTPConnection) -> TokenCache:
    """Return the cache of recently authenticated tokens."""
    return runtime_of(connection).token_cache


async def get_auth_limiter(connection: HTTPConnection) -> AuthFailureLimiter:
    """Return the limiter of failed authentications per client."""
    return runtime_of(connection).auth_limiter


SessionDep = Annotated[Session, Depends(get_session)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
EngineDep = Annotated[Engine, Depends(get_engine)]
SessionFactoryDep = Annotated[sessionmaker[Session], Depends(get_session_factory)]
SceneDep = Annotated[SceneSync, Depends(get_scene)]
ViserPortDep = Annotated[int, Depends(get_viser_port)]
ExecutorDep = Annotated[RunExecutor | None, Depends(get_executor)]
TwinDep = Annotated[Twin | None, Depends(get_twin)]
TaskRunnerDep = Annotated[TaskRunner, Depends(get_task_runner)]
FollowTasksDep = Annotated[FollowTasks, Depends(get_follow_tasks)]
FramesDep = Annotated[LatestFrames, Depends(get_latest_frames)]
HealthDep = Annotated[CameraHealthBook, Depends(get_camera_health)]
TrackingDep = Annotated[TrackingService | None, Depends(get_tracking)]
LiveTargetsDep = Annotated[LiveTargets, Depends(get_live_targets)]
ZonesDep = Annotated[ZoneService | None, Depends(get_zones)]
HomeDep = Annotated[HomePublisher | None, Depends(get_home)]
FrigateDep = Annotated[FrigateSource | None, Depends(get_frigate)]
TokenCacheDep = Annotated[TokenCache, Depends(get_token_cache)]
AuthLimiterDep = Annotated[AuthFailureLimiter, Depends(get_auth_limiter)]


class AuthRefused(Exception):
    """A credential was refused: the HTTP status, what to tell the client, extra headers."""

    def __init__(self, status_code: int, detail: str, headers: dict[str, str] | None = None):
        super().__init__(detail)
        self.status_code = status_code
        self.detail = detail
        self.headers = headers or {}

    def http(self) -> HTTPException:
        """Return the HTTPException answering the request."""
        return HTTPException(self.status_code, detail=self.detail, headers=self.headers)


def clear_cookie_header(secure: bool = False) -> str:
    """Return the Set-Cookie value that removes the session cookie."""
    flags = "; Secure" if secure else ""
    return f"{SESSION_COOKIE}=; Max-Age=0; Path=/; HttpOnly; SameSite=Strict{flags}"


def client_key(connection: HTTPConnection) -> str:
    """Return the key under which a client's failed authentications are counted (its address;
    behind a reverse proxy, the proxy's)."""
    return connection.client.host if connection.client else "unknown"


def same_origin(connection: HTTPConnection, origin: str, settings: Settings) -> bool:
    """Return True when `origin` is the service's own (the Host the client used) or one the
    settings allow for CORS."""
    if origin in settings.cors_origins:
        return True
    host = connection.headers.get("host", "")
    scheme = "https" if connection.url.scheme in ("https", "wss") else "http"
    return origin == f"{scheme}://{host}"


def _authenticate(
    factory: sessionmaker[Session], token: str, configured: str | None
) -> Principal | None:
    with factory() as session:
        return authenticate(session, token, configured)


async def principal_of(connection: HTTPConnection, token: str) -> Principal | None:
    """Return the principal of `token` (cached for a few seconds), None when refused."""
    runtime = runtime_of(connection)
    settings = runtime.settings
    tokens = runtime.token_cache
    principal = tokens.get(token)
    if principal is None:
        configured = settings.admin_token.get_secret_value() if settings.admin_token else None
        principal = await run_in_threadpool(
            _authenticate, runtime.session_factory, token, configured
        )
        if principal is not None:
            tokens.put(token, principal)
    return principal


async def _bearer_principal(connection: HTTPConnection, token: str) -> Principal:
    """Return the principal of a bearer token, counting a refusal against the client."""
    limiter = runtime_of(connection).auth_limiter
    key = client_key(connection)
    wait = limiter.retry_after(key)
    if wait is not None:
        raise AuthRefused(
            status.HTTP_429_TOO_MANY_REQUESTS,
            f"too many failed authentications from this client; try again in {wait} s",
            {"Retry-After": str(wait)},
        )
    principal = await principal_of(connection, token)
    # A session token is a cookie's value: as a bearer token it is refused like any unknown one.
    if principal is None or principal.kind == KIND_SESSION:
        limiter.failed(key)
        raise AuthRefused(
            status.HTTP_401_UNAUTHORIZED,
            "the bearer token is unknown or revoked",
            {"WWW-Authenticate": "Bearer"},
        )
    return principal


async def _cookie_principal(connection: HTTPConnection, token: str) -> Principal:
    """Return the principal of a session cookie. Session tokens are 256 random bits, so a
    refused cookie (expired, signed out) is not counted as a guess: a browser coming back after
    its session ended sends several at once."""
    principal = await principal_of(connection, token)
    if principal is None or principal.kind != KIND_SESSION:
        secure = connection.url.scheme in ("https", "wss")
        raise AuthRefused(
            status.HTTP_401_UNAUTHORIZED,
            "the dashboard session ended (expired or signed out); sign in again",
            {"WWW-Authenticate": "Bearer", "Set-Cookie": clear_cookie_header(secure)},
        )
    return principal


def check_csrf(request: Request, settings: Settings, session_token: str) -> None:
    """Refuse a write through the session cookie without the session's CSRF token, or from
    another origin."""
    origin = request.headers.get("origin")
    if origin is not None and not same_origin(request, origin, settings):
        raise AuthRefused(
            status.HTTP_403_FORBIDDEN, f"a dashboard session may not be used from {origin}"
        )
    sent = request.headers.get(CSRF_HEADER, "")
    if not hmac_equal(sent, csrf_token(session_token)):
        raise AuthRefused(
            status.HTTP_403_FORBIDDEN,
            f"a write through the dashboard session needs its {CSRF_HEADER} header (GET "
            "/api/v1/session returns it); scripts use Authorization: Bearer <token>",
        )


def hmac_equal(a: str, b: str) -> bool:
    """Return a == b in time independent of where they differ."""
    return hmac.compare_digest(a.encode(), b.encode())


async def _body_camera_ids(request: Request) -> set[int] | None:
    """Return the cameras an observation batch speaks for, None when the body has another
    shape (its validation refuses it)."""
    try:
        body: Any = await request.json()
        return {int(o["camera_id"]) for o in body.get("observations", ())} | {
            int(f["camera_id"]) for f in body.get("empty_frames", ())
        }
    except (ValueError, TypeError, KeyError, AttributeError):
        return None


async def _check_ingest(request: Request, principal: Principal) -> None:
    """Refuse an ingest-only credential outside INGEST_ROUTES, or for another camera."""
    path = request.url.path
    if not any(request.method == m and rx.fullmatch(path) for m, rx in INGEST_ROUTES):
        raise AuthRefused(
            status.HTTP_403_FORBIDDEN,
            "an ingest token may only post observations, heartbeats and frames and read its "
            "cameras and their streams",
        )
    if principal.camera_ids is None:
        return
    if "camera_id" in request.path_params:
        cameras: set[int] | None = {int(request.path_params["camera_id"])}
    else:
        cameras = await _body_camera_ids(request)
    foreign = sorted(c for c in (cameras or set()) if not principal.speaks_for(c))
    if cameras is None or foreign:
        raise AuthRefused(
            status.HTTP_403_FORBIDDEN,
            f"this ingest token speaks for cameras {sorted(principal.camera_ids)} only, "
            f"not {foreign or 'an unreadable body'}",
        )


async def caller(
    request: Request,
    settings: Settings,
    credentials: HTTPAuthorizationCredentials | None,
    session_token: str | None,
) -> tuple[Principal | None, str | None]:
    """Return the calling principal (None when anonymous) and the session token when the
    cookie authenticated it. Raises AuthRefused."""
    if credentials is not None and credentials.scheme.lower() == "bearer":
        return await _bearer_principal(request, credentials.credentials), None
    if session_token:
        principal = await _cookie_principal(request, session_token)
        return principal, session_token
    return None, None


def _requiring(right: str):
    async def dependency(
        request: Request,
        settings: SettingsDep,
        credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)],
        session_token: Annotated[str | None, Depends(cookie_scheme)],
    ) -> Principal | None:
        try:
            principal, via_cookie = await caller(request, settings, credentials, session_token)
            if principal is None:
                if right == "read" and settings.public_reads:
                    return None
                raise AuthRefused(
                    status.HTTP_401_UNAUTHORIZED,
                    "this endpoint needs Authorization: Bearer <token> (or a dashboard sign-in)",
                    {"WWW-Authenticate": "Bearer"},
                )
            if via_cookie is not None and request.method not in SAFE_METHODS:
                check_csrf(request, settings, via_cookie)
            if not principal.can(right):
                if principal.can("ingest") and right in ("read", "write"):
                    await _check_ingest(request, principal)
                    return principal
                raise AuthRefused(status.HTTP_403_FORBIDDEN, f"the token lacks the '{right}' scope")
            return principal
        except AuthRefused as refused:
            raise refused.http() from None

    dependency.__name__ = f"require_{right}"
    return dependency


require_read = _requiring("read")
require_write = _requiring("write")
require_admin = _requiring("admin")

ReadAccess = Depends(require_read)
WriteAccess = Depends(require_write)
AdminAccess = Depends(require_admin)


@dataclass(frozen=True)
class WebSocketCaller:
    """Who opened a WebSocket (None: anonymous, with public reads) and the subprotocol to
    answer with (None: none)."""

    principal: Principal | None
    subprotocol: str | None


async def websocket_caller(
    websocket: WebSocket, right: str = "read", protocols: tuple[str, ...] = ("intspace",)
) -> WebSocketCaller:
    """Return who opens `websocket`: a bearer token in the Authorization header or offered as
    `bearer.<token>` in Sec-WebSocket-Protocol, or the session cookie from the service's own
    origin. The answered subprotocol is the first offered of `protocols` (never the token).
    Raises AuthRefused."""
    settings = runtime_of(websocket).settings
    offered = [p.strip() for p in websocket.scope.get("subprotocols", [])]
    chosen = next((p for p in offered if p in protocols or _prefixed(p, protocols)), None)
    authorization = websocket.headers.get("authorization", "")
    scheme, _, value = authorization.partition(" ")
    token = value.strip() if scheme.lower() == "bearer" and value.strip() else None
    if token is None:
        token = next(
            (p[len(WS_BEARER_PREFIX) :] for p in offered if p.startswith(WS_BEARER_PREFIX)), None
        )
    if token is not None:
        principal: Principal | None = await _bearer_principal(websocket, token)
    elif cookie := websocket.cookies.get(SESSION_COOKIE):
        origin = websocket.headers.get("origin")
        if origin is None or not same_origin(websocket, origin, settings):
            raise AuthRefused(
                status.HTTP_403_FORBIDDEN,
                f"a dashboard session opens WebSockets only from the service's own page, not "
                f"from {origin or 'a client without an Origin'}",
            )
        principal = await _cookie_principal(websocket, cookie)
    else:
        principal = None
    if principal is None:
        if right == "read" and settings.public_reads:
            return WebSocketCaller(None, chosen)
        raise AuthRefused(
            status.HTTP_401_UNAUTHORIZED,
            "missing credentials: send Authorization: Bearer <token>, offer "
            "'bearer.<token>' in Sec-WebSocket-Protocol, or sign in to the dashboard",
        )
    if not principal.can(right):
        raise AuthRefused(status.HTTP_403_FORBIDDEN, f"the token lacks the '{right}' scope")
    return WebSocketCaller(principal, chosen)


def _prefixed(offer: str, protocols: tuple[str, ...]) -> bool:
    return any(p.endswith("*") and offer.startswith(p[:-1]) for p in protocols)


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
