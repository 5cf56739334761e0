"""Tokens and browser sessions: generated at random, stored as SHA-256 digests, checked in
constant time.

Two kinds of credential reach the service:

* API tokens ("isp_..."), sent by scripts and camera nodes in `Authorization: Bearer`. Their
  scopes: read (GET everything), write (also change things), admin (also tokens), and ingest
  (a camera node: post its observations and heartbeats, read its own camera and stream, and
  nothing else; optionally bound to a list of cameras).
* Browser sessions ("iss_..."), made when someone signs in to the dashboard with a read, write or
  admin token; carried only by an HttpOnly SameSite=Strict cookie, they expire, end when their
  parent token is revoked, and writes through them need the session's CSRF token.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time
from dataclasses import dataclass

from pydantic import SecretStr
from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from server.db.models import ApiToken
from server.schemas.tokens import Scope

SCOPES = ("read", "write", "admin", "ingest")
# What each scope grants: admin implies write implies read; write also lets a script ingest.
_GRANTS = {
    "read": {"read"},
    "ingest": {"ingest"},
    "write": {"read", "write", "ingest"},
    "admin": {"read", "write", "ingest", "admin"},
}
# Scopes that alone name a credential's rights, widest first; the narrow ones, in sorted order.
_WIDEST: tuple[Scope, ...] = ("admin", "write")
_NARROW: tuple[Scope, ...] = ("ingest", "read")
ADMIN_TOKEN_NAME = "admin (first run)"
# A configured admin token shorter than this is refused at start: 16 random characters from the
# 64-symbol URL-safe alphabet are 96 bits, beyond guessing even without the rate limit.
MIN_ADMIN_TOKEN_LENGTH = 16
API_PREFIX = "isp_"
SESSION_PREFIX = "iss_"
KIND_API = "api"
KIND_SESSION = "session"
KIND_CONFIGURED = "configured"


@dataclass(frozen=True)
class Principal:
    """Who is calling: the token's id (None for the configured admin token), its name, rights,
    kind (api, session or configured), the cameras an ingest token speaks for (None: any) and
    when a session ends (Unix s; None for tokens)."""

    token_id: int | None
    name: str
    rights: frozenset[str]
    kind: str = KIND_API
    camera_ids: frozenset[int] | None = None
    expires_at: float | None = None

    def can(self, right: str) -> bool:
        """Return True when the credential grants `right` (read, write, admin or ingest)."""
        return right in self.rights

    def speaks_for(self, camera_id: int) -> bool:
        """Return True when an ingest credential may act for camera `camera_id`."""
        return self.camera_ids is None or camera_id in self.camera_ids

    @property
    def scopes(self) -> list[Scope]:
        """Return the smallest list of scopes granting these rights."""
        for scope in _WIDEST:
            if self.rights == frozenset(_GRANTS[scope]):
                return [scope]
        return [s for s in _NARROW if s in self.rights]


def hash_token(token: str) -> str:
    """Return the hex SHA-256 digest under which a token is stored."""
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def rights_of(scopes: list[str]) -> frozenset[str]:
    """Return every right the scopes grant."""
    rights: set[str] = set()
    for scope in scopes:
        rights |= _GRANTS.get(scope, set())
    return frozenset(rights)


def csrf_token(session_token: str) -> str:
    """Return the CSRF token of a browser session: HMAC-SHA256 of a fixed label keyed by the
    session token, so every API process derives it from the cookie alone, and a page that
    cannot read the HttpOnly cookie learns it only from GET /session (same origin)."""
    return hmac.new(session_token.encode("utf-8"), b"intspace csrf", hashlib.sha256).hexdigest()


def create_token(
    session: Session, name: str, scopes: list[str], camera_ids: list[int] | None = None
) -> tuple[ApiToken, str]:
    """Add a new API token (not committed); return its row and the token, never stored."""
    token = API_PREFIX + secrets.token_urlsafe(32)
    row = ApiToken(
        name=name,
        token_hash=hash_token(token),
        scopes=sorted(set(scopes)),
        kind=KIND_API,
        camera_ids=None if camera_ids is None else sorted(set(camera_ids)),
    )
    session.add(row)
    session.flush()
    return row, token


def create_session(
    session: Session, principal: Principal, ttl_s: float, now: float | None = None
) -> tuple[ApiToken, str]:
    """Add (and commit) a browser session with `principal`'s rights for `ttl_s` seconds; return
    its row and its token (the cookie's value, never stored). Expired sessions are purged."""
    now = time.time() if now is None else now
    session.execute(
        delete(ApiToken).where(ApiToken.kind == KIND_SESSION, ApiToken.expires_at < now)
    )
    token = SESSION_PREFIX + secrets.token_urlsafe(32)
    row = ApiToken(
        name=f"browser session of {principal.name}"[:200],
        token_hash=hash_token(token),
        scopes=principal.scopes,
        kind=KIND_SESSION,
        expires_at=now + ttl_s,
        parent_id=principal.token_id,
    )
    session.add(row)
    session.commit()
    return row, token


def end_session(session: Session, token: str) -> bool:
    """Revoke the browser session `token` (committed); return False when it was not one."""
    row = session.scalar(
        select(ApiToken).where(
            ApiToken.token_hash == hash_token(token), ApiToken.kind == KIND_SESSION
        )
    )
    if row is None:
        return False
    row.revoked = True
    session.commit()
    return True


def authenticate(
    session: Session, token: str, admin_token: str | None, now: float | None = None
) -> Principal | None:
    """Return the principal of `token` (an API token, a session, or the configured admin
    token), None when it is unknown, revoked, expired, or its parent token is revoked."""
    if admin_token is not None and hmac.compare_digest(token.encode(), admin_token.encode()):
        return Principal(
            token_id=None,
            name="admin (configured)",
            rights=rights_of(["admin"]),
            kind=KIND_CONFIGURED,
        )
    row = session.scalar(
        select(ApiToken).where(
            ApiToken.token_hash == hash_token(token), ApiToken.revoked.is_(False)
        )
    )
    if row is None:
        return None
    if row.expires_at is not None and row.expires_at <= (time.time() if now is None else now):
        return None
    if row.parent_id is not None:
        parent = session.get(ApiToken, row.parent_id)
        if parent is None or parent.revoked:
            return None
    return Principal(
        token_id=row.id,
        name=row.name,
        rights=rights_of(row.scopes),
        kind=row.kind,
        camera_ids=None if row.camera_ids is None else frozenset(row.camera_ids),
        expires_at=row.expires_at,
    )


def ensure_admin_token(session: Session, configured: str | None) -> str | None:
    """Create the first-run admin token when no admin token exists; return it (to print once),
    or None when one exists already or INTSPACE_ADMIN_TOKEN provides it."""
    if configured is not None:
        return None
    rows = session.scalars(
        select(ApiToken).where(ApiToken.revoked.is_(False), ApiToken.kind == KIND_API)
    )
    if any("admin" in row.scopes for row in rows):
        return None
    _, token = create_token(session, ADMIN_TOKEN_NAME, ["admin"])
    session.commit()
    return token


class TokenCache:
    """Recently authenticated credentials (by digest) for `ttl` seconds (never past a session's
    end), so that a read costs no token query. Revoking through this process clears it; other
    processes see a revocation within `ttl`."""

    def __init__(self, ttl: float = 5.0, max_entries: int = 1024) -> None:
        self._ttl = ttl
        self._max = max_entries
        self._entries: dict[str, tuple[float, float | None, Principal]] = {}
        self._lock = threading.Lock()

    def get(self, token: str) -> Principal | None:
        """Return the cached principal of `token`, None when absent or expired."""
        key = hash_token(token)
        with self._lock:
            entry = self._entries.get(key)
        if entry is None or entry[0] < time.monotonic():
            return None
        if entry[1] is not None and entry[1] <= time.time():
            return None
        return entry[2]

    def put(self, token: str, principal: Principal) -> None:
        """Remember that `token` authenticates as `principal`."""
        with self._lock:
            if len(self._entries) >= self._max:
                self._entries.clear()
            self._entries[hash_token(token)] = (
                time.monotonic() + self._ttl,
                principal.expires_at,
                principal,
            )

    def clear(self) -> None:
        """Forget every token (after a revocation or a sign-out)."""
        with self._lock:
            self._entries.clear()


def admin_token_problem(admin_token: SecretStr | None) -> str | None:
    """Return why a configured admin token is refused (too short), None when it is fine."""
    if admin_token is None:
        return None
    length = len(admin_token.get_secret_value())
    if length >= MIN_ADMIN_TOKEN_LENGTH:
        return None
    return (
        f"INTSPACE_ADMIN_TOKEN has {length} characters; an admin token needs at least "
        f'{MIN_ADMIN_TOKEN_LENGTH} (make one with: python -c "import secrets; '
        f'print(secrets.token_urlsafe(24))")'
    )
