"""Bearer tokens: generated at random, stored as SHA-256 digests, checked in constant time."""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.orm import Session

from server.db.models import ApiToken

SCOPES = ("read", "write", "admin")
# What each scope grants: admin implies write implies read.
_GRANTS = {"read": {"read"}, "write": {"read", "write"}, "admin": {"read", "write", "admin"}}
ADMIN_TOKEN_NAME = "admin (first run)"


@dataclass(frozen=True)
class Principal:
    """Who is calling: the token's id (None for the configured admin token) and its rights."""

    token_id: int | None
    name: str
    rights: frozenset[str]

    def can(self, right: str) -> bool:
        """Return True when the token grants `right` (read, write or admin)."""
        return right in self.rights


def hash_token(token: str) -> str:
    """Return the hex SHA-256 digest under which a token is stored."""
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def rights_of(scopes: list[str]) -> frozenset[str]:
    """Return every right the scopes grant."""
    rights: set[str] = set()
    for scope in scopes:
        rights |= _GRANTS.get(scope, set())
    return frozenset(rights)


def create_token(session: Session, name: str, scopes: list[str]) -> tuple[ApiToken, str]:
    """Add a new token (not committed); return its row and the token, which is never stored."""
    token = "isp_" + secrets.token_urlsafe(32)
    row = ApiToken(name=name, token_hash=hash_token(token), scopes=sorted(set(scopes)))
    session.add(row)
    session.flush()
    return row, token


def authenticate(session: Session, token: str, admin_token: str | None) -> Principal | None:
    """Return the principal of `token`, None when it is unknown or revoked."""
    if admin_token is not None and hmac.compare_digest(token.encode(), admin_token.encode()):
        return Principal(token_id=None, name="admin (configured)", rights=rights_of(["admin"]))
    row = session.scalar(
        select(ApiToken).where(
            ApiToken.token_hash == hash_token(token), ApiToken.revoked.is_(False)
        )
    )
    if row is None:
        return None
    return Principal(token_id=row.id, name=row.name, rights=rights_of(row.scopes))


def ensure_admin_token(session: Session, configured: str | None) -> str | None:
    """Create the first-run admin token when no admin token exists; return it (to print once),
    or None when one exists already or INTSPACE_ADMIN_TOKEN provides it."""
    if configured is not None:
        return None
    for row in session.scalars(select(ApiToken).where(ApiToken.revoked.is_(False))):
        if "admin" in row.scopes:
            return None
    _, token = create_token(session, ADMIN_TOKEN_NAME, ["admin"])
    session.commit()
    return token


class TokenCache:
    """Recently authenticated tokens (by digest) for `ttl` seconds, so that a read costs no
    token query. Revoking through this process clears it; other processes see a revocation
    within `ttl`."""

    def __init__(self, ttl: float = 5.0, max_entries: int = 1024) -> None:
        self._ttl = ttl
        self._max = max_entries
        self._entries: dict[str, tuple[float, Principal]] = {}
        self._lock = threading.Lock()

    def get(self, token: str) -> Principal | None:
        """Return the cached principal of `token`, None when absent or expired."""
        key = hash_token(token)
        with self._lock:
            entry = self._entries.get(key)
        if entry is None or entry[0] < time.monotonic():
            return None
        return entry[1]

    def put(self, token: str, principal: Principal) -> None:
        """Remember that `token` authenticates as `principal`."""
        with self._lock:
            if len(self._entries) >= self._max:
                self._entries.clear()
            self._entries[hash_token(token)] = (time.monotonic() + self._ttl, principal)

    def clear(self) -> None:
        """Forget every token (after a revocation)."""
        with self._lock:
            self._entries.clear()
