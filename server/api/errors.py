"""Every error leaves as problem details JSON (RFC 9457) naming the fields and the reasons.

Unhandled errors are answered by `UnhandledErrors`, an ASGI middleware inside Starlette's own
error middleware: that one re-raises after answering, and uvicorn then drops the keep-alive
connection; this one answers a 500 with a request id, logs the traceback once under that id and
leaves the connection usable. Storage failures (full disk, a deleted or read-only database file)
are named: 507 or 503, never a generic 500.
"""

from __future__ import annotations

import logging
import re
import uuid
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DBAPIError, IntegrityError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match, Mount
from starlette.types import Receive, Scope, Send

from core.errors import IntspaceError
from server.db.session import StorageFailure
from server.middleware import HttpMiddleware, StartWatch
from server.schemas.common import FieldError, Problem

log = logging.getLogger(__name__)

PROBLEM_MEDIA_TYPE = "application/problem+json"
# A 422 lists this many field errors, then says how many there were in all: a body with 60,000
# mistakes must not cost an 8.8 MB answer.
MAX_LISTED_ERRORS = 20


class FieldProblem(Exception):
    """A request that is well-formed but names something wrong (e.g. an unknown space_id)."""

    def __init__(self, status: int, field: str, reason: str, location: str = "body") -> None:
        super().__init__(reason)
        self.status = status
        self.errors = [FieldError(field=field, location=location, reason=reason)]


def problem_response(
    status: int,
    detail: str,
    errors: list[FieldError] | None = None,
    headers: dict[str, str] | None = None,
    *,
    error_count: int | None = None,
    request_id: str | None = None,
) -> JSONResponse:
    """Return a problem-details response (at most MAX_LISTED_ERRORS field errors listed;
    `error_count` says how many there were when more)."""
    title = HTTPStatus(status).phrase if status in HTTPStatus._value2member_map_ else "Error"
    errors = errors or []
    body = Problem(
        title=title,
        status=status,
        detail=detail,
        errors=errors[:MAX_LISTED_ERRORS],
        error_count=len(errors) if error_count is None else error_count,
        request_id=request_id,
    )
    return JSONResponse(
        body.model_dump(exclude_none=True),
        status_code=status,
        headers=headers,
        media_type=PROBLEM_MEDIA_TYPE,
    )


def _field_errors(errors: Any) -> list[FieldError]:
    out = []
    for error in errors:
        loc = [str(part) for part in error.get("loc", ())]
        location = loc[0] if loc else "body"
        field = ".".join(loc[1:]) or location
        out.append(FieldError(field=field, location=location, reason=str(error.get("msg", ""))))
    return out


async def _validation(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    raw = exc.errors()
    errors = _field_errors(raw[:MAX_LISTED_ERRORS])
    names = ", ".join(sorted({e.field for e in errors}))
    more = len(raw) - len(errors)
    detail = f"invalid request: {names}" + (
        f" and {more} more error(s) ({len(raw)} in all; the first {len(errors)} are listed)"
        if more
        else ""
    )
    return problem_response(422, detail, errors, error_count=len(raw))


async def _http(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    detail = exc.detail if isinstance(exc.detail, str) else HTTPStatus(exc.status_code).phrase
    return problem_response(exc.status_code, detail, headers=getattr(exc, "headers", None))


async def _field_problem(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, FieldProblem)
    return problem_response(exc.status, str(exc), exc.errors)


async def _core_error(_: Request, exc: Exception) -> JSONResponse:
    return problem_response(422, f"{type(exc).__name__}: {exc}")


async def _integrity(_: Request, exc: Exception) -> JSONResponse:
    log.warning("integrity error: %s", exc)
    return problem_response(409, "the change conflicts with existing data")


# What the database drivers say when the storage, not the request, is at fault. SQLite:
# SQLITE_FULL, SQLITE_READONLY, SQLITE_IOERR, SQLITE_CANTOPEN, SQLITE_BUSY; PostgreSQL: class 53
# (insufficient resources: 53100 disk full) and 25006 (read-only transaction).
_FULL = re.compile(r"database or disk is full|no space left on device|disk full|could not extend")
_BROKEN = re.compile(
    r"readonly database|read-only|disk i/o error|unable to open database|database disk image "
    r"is malformed|no such table"
)
_BUSY = re.compile(r"database is locked|database table is locked")


def storage_problem(exc: BaseException) -> JSONResponse | None:
    """Return the 507/503 naming a storage failure in `exc`, None when `exc` is not one."""
    if isinstance(exc, StorageFailure):
        log.error("storage failing: %s", exc)
        return problem_response(503, f"storage failing: {exc}", headers={"Retry-After": "30"})
    if not isinstance(exc, DBAPIError):
        return None
    message = str(exc.orig if exc.orig is not None else exc).lower()
    if _FULL.search(message):
        log.error("storage full: %s", message)
        return problem_response(
            507,
            "storage full: the database cannot grow (disk full or its size cap reached); "
            "nothing was written. Free space, or lower the retention (INTSPACE_TRACK_RETENTION_S, "
            "INTSPACE_DETECTION_RETENTION_S)",
        )
    if _BUSY.search(message):
        log.warning("storage busy: %s", message)
        return problem_response(
            503,
            "storage busy: the database stayed locked by another writer; nothing was written, "
            "try again",
            headers={"Retry-After": "1"},
        )
    if _BROKEN.search(message):
        log.error("storage failing: %s", message)
        return problem_response(
            503,
            f"storage failing: {message.splitlines()[0][:200]}; nothing was written. Check the "
            "data directory (deleted, read-only or unmounted?)",
            headers={"Retry-After": "30"},
        )
    return None


class UnhandledErrors(HttpMiddleware):
    """ASGI middleware answering every unhandled error with a problem-details 500 carrying a
    request id (also in the X-Request-ID header), its traceback logged once under that id, and
    storage errors with 507/503 naming them; the connection stays open."""

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        watch = StartWatch(send)
        try:
            await self.app(scope, receive, watch)
        except Exception as exc:
            if watch.started:
                # Half an answer is out: nothing better than letting the server close it.
                raise
            response = storage_problem(exc)
            if response is None:
                request_id = uuid.uuid4().hex
                log.error(
                    "unhandled error, request id %s, on %s %s",
                    request_id,
                    scope.get("method"),
                    scope.get("path"),
                    exc_info=exc,
                )
                response = problem_response(
                    500,
                    f"internal error; the server log has its traceback under request id "
                    f"{request_id}",
                    headers={"X-Request-ID": request_id},
                    request_id=request_id,
                )
            await response(scope, receive, send)


async def _storage(_: Request, exc: Exception) -> JSONResponse:
    response = storage_problem(exc)
    if response is None:
        raise exc
    return response


def install_error_handlers(app: FastAPI) -> None:
    """Register the problem-details handlers and the unhandled-error middleware on the app."""
    app.add_exception_handler(RequestValidationError, _validation)
    app.add_exception_handler(StarletteHTTPException, _http)
    app.add_exception_handler(FieldProblem, _field_problem)
    app.add_exception_handler(IntspaceError, _core_error)
    app.add_exception_handler(IntegrityError, _integrity)
    app.add_exception_handler(StorageFailure, _storage)
    # Not an exception handler for Exception: Starlette runs that one in its outermost
    # middleware, which re-raises afterwards and so costs the client its connection.
    app.add_middleware(UnhandledErrors)


_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")


def install_api_fallback(app: FastAPI, prefix: str) -> None:
    """Answer every path under `prefix` that no API route takes, so that the static mount at /
    never does: 405 with the route's real Allow when the path exists for other methods, 404
    naming the path otherwise. Call after every API router is included."""

    async def fallback(request: Request, rest_of_path: str) -> JSONResponse:
        # The methods some API route takes on this path (FULL match), asked method by method:
        # routers may be nested and lazily prefixed, the question is the router's own.
        allowed = {
            method
            for method in _METHODS
            for route in app.router.routes
            if not isinstance(route, Mount)
            and getattr(route, "endpoint", None) is not fallback
            and route.matches({**request.scope, "method": method})[0] == Match.FULL
        }
        if allowed:
            return problem_response(
                405,
                f"{request.method} is not allowed on {request.url.path}; allowed: "
                + ", ".join(sorted(allowed)),
                headers={"Allow": ", ".join(sorted(allowed))},
            )
        return problem_response(404, f"no API resource at {request.url.path}")

    app.add_api_route(
        prefix + "/{rest_of_path:path}", fallback, methods=list(_METHODS), include_in_schema=False
    )


# Documented on every route that can produce them.
PROBLEM_RESPONSES: dict[int | str, dict[str, Any]] = {
    status: {"model": Problem, "content": {PROBLEM_MEDIA_TYPE: {}}}
    for status in (400, 401, 403, 404, 409, 413, 415, 422, 503, 507)
}
