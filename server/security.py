"""What every response and log line of the service promises: security headers on each HTTP
answer, failed authentication slowed per client, and no secret in a log line."""

from __future__ import annotations

import logging
import math
import re
import time
from collections.abc import Iterable

from limits import RateLimitItem, parse
from limits.storage import MemoryStorage
from limits.strategies import MovingWindowRateLimiter
from starlette.types import Message, Receive, Scope, Send

from server.middleware import HttpMiddleware

# The proxied 3D scene (viser's single-file client) runs inline scripts, evaluates strings and
# compiles WebAssembly; every other page, the dashboard and the API docs included, runs only
# scripts from the service.
SCENE_PATH = "/api/v1/scene/view"
DASHBOARD_CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
    "font-src 'self' data:; connect-src 'self'; frame-src 'self'; frame-ancestors 'self'; "
    "base-uri 'self'; form-action 'self'; object-src 'none'"
)
SCENE_CSP = (
    "default-src 'self'; script-src 'self' 'unsafe-inline' 'unsafe-eval'; "
    "style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; font-src 'self' data:; "
    "connect-src 'self' data: blob:; worker-src 'self' blob:; frame-ancestors 'self'; "
    "base-uri 'self'; form-action 'self'; object-src 'none'"
)
_COMMON = (
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"same-origin"),
    (b"cross-origin-opener-policy", b"same-origin"),
)


class SecurityHeaders(HttpMiddleware):
    """ASGI middleware adding X-Content-Type-Options, Referrer-Policy and a
    Content-Security-Policy (frame-ancestors 'self': only the service may frame its pages) to
    every HTTP response that does not set them itself."""

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        csp = SCENE_CSP if scope["path"].startswith(SCENE_PATH) else DASHBOARD_CSP
        extra = (*_COMMON, (b"content-security-policy", csp.encode("ascii")))

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                present = {name.lower() for name, _ in headers}
                headers.extend((k, v) for k, v in extra if k not in present)
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, send_with_headers)


class AuthFailureLimiter:
    """Failed authentications per client in a moving window (the `limits` library): once a
    client has failed `limit` (e.g. "10/minute") times, it is answered 429 until the window
    lets it try again."""

    def __init__(self, limit: str) -> None:
        self.item: RateLimitItem = parse(limit)
        self._limiter = MovingWindowRateLimiter(MemoryStorage())

    def retry_after(self, client: str) -> int | None:
        """Return the seconds `client` must wait before its next attempt, None when it may try."""
        if self._limiter.test(self.item, client):
            return None
        reset, _ = self._limiter.get_window_stats(self.item, client)
        return max(1, math.ceil(reset - time.time()))

    def failed(self, client: str) -> None:
        """Count one failed authentication of `client`."""
        self._limiter.hit(self.item, client)


# Secrets that could reach a log line: a token in a query string (clients that still send one),
# an API or session token anywhere, an Authorization header's value.
_QUERY_SECRET = re.compile(
    r"(?i)([?&](?:token|access_token|api_key|apikey|session|password)=)[^&\s\"']+"
)
_TOKEN = re.compile(r"\b(isp|iss)_[A-Za-z0-9_-]{16,}")
_BEARER = re.compile(r"(?i)\b(bearer)\s+[A-Za-z0-9._~+/=-]+")
REDACTED = "[redacted]"


class RedactSecrets(logging.Filter):
    """A logging filter replacing tokens (and the configured secrets) in a record's message."""

    def __init__(self, secrets: Iterable[str] = ()) -> None:
        super().__init__()
        self._secrets = [s for s in secrets if s]

    def redact(self, text: str) -> str:
        """Return `text` with every secret it holds replaced by [redacted]."""
        for secret in self._secrets:
            text = text.replace(secret, REDACTED)
        text = _QUERY_SECRET.sub(rf"\1{REDACTED}", text)
        text = _TOKEN.sub(rf"\1_{REDACTED}", text)
        return _BEARER.sub(rf"\1 {REDACTED}", text)

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            message = record.getMessage()
        except Exception:  # a malformed record is logging's problem to report, not ours
            return True
        clean = self.redact(message)
        if clean != message:
            record.msg, record.args = clean, None
        return True


_LOGGERS = ("", "uvicorn", "uvicorn.access", "uvicorn.error", "websockets", "httpx")


def install_log_redaction(secrets: Iterable[str] = ()) -> RedactSecrets:
    """Attach a RedactSecrets filter to the service's loggers and their handlers (call it after
    uvicorn configured logging, i.e. at start-up); return the filter."""
    redact = RedactSecrets(secrets)
    for name in _LOGGERS:
        logger = logging.getLogger(name)
        for target in (logger, *logger.handlers):
            for old in [f for f in target.filters if isinstance(f, RedactSecrets)]:
                target.removeFilter(old)  # an earlier app's, with its secrets
            target.addFilter(redact)
    return redact
