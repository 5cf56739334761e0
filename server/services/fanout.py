"""Messages between the service's processes over PostgreSQL LISTEN/NOTIFY.

Several `intspace serve` processes on one PostgreSQL database (spec 06, "scale past one box")
each keep the live targets in memory for their WebSocket streams and their scene; what one
process's tracker computes reaches the others as small JSON notifications. `Fanout` listens on a
dedicated autocommit connection in a thread (psycopg's `Connection.notifies()`), hands each
message to the handler of its channel, and reconnects with back-off when the connection drops
(messages sent meanwhile are lost: the receivers catch up from the database, see
server.services.tracking). It publishes on a second connection.

PostgreSQL caps a notification's payload below 8000 bytes: `publish` splits a list of items
over as many notifications as it needs, each below `PAYLOAD_LIMIT`. Every message names its
sender (`o`, a random id per process), and a process never receives its own.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import uuid
from collections.abc import Callable, Sequence
from typing import Any

import psycopg
from psycopg import sql
from sqlalchemy.engine import make_url

from server.services._loop_thread import LoopThread

log = logging.getLogger(__name__)

# Bytes of one notification's payload at most (PostgreSQL refuses 8000 and more).
PAYLOAD_LIMIT = 7900
# Seconds between reconnection attempts of the listener, doubling up to the last.
_BACKOFF_S = (0.2, 0.5, 1.0, 2.0)
# Seconds the listener waits for a notification before checking whether to stop.
_POLL_S = 0.5

Handler = Callable[[dict[str, Any]], None]


def conninfo(database_url: str) -> str:
    """Return the libpq URI of an SQLAlchemy PostgreSQL URL (driver name dropped)."""
    url = make_url(database_url)
    if url.get_backend_name() != "postgresql":
        raise ValueError(f"LISTEN/NOTIFY needs PostgreSQL, not {url.get_backend_name()}")
    return url.set(drivername="postgresql").render_as_string(hide_password=False)


def chunk_payloads(
    base: dict[str, Any], items: Sequence[Any], limit: int = PAYLOAD_LIMIT
) -> list[str]:
    """Return JSON texts {**base, "items": [...]}, each below `limit` bytes, that together
    carry every item in order. An item too large for one message raises ValueError."""
    head = json.dumps({**base, "items": []}, separators=(",", ":"))[:-2]  # up to '"items":['
    room = limit - len(head.encode()) - 2  # the closing ']}'
    out: list[str] = []
    parts: list[str] = []
    size = 0
    for item in items:
        text = json.dumps(item, separators=(",", ":"))
        n = len(text.encode()) + (1 if parts else 0)
        if len(text.encode()) > room:
            raise ValueError(f"one item of {len(text.encode())} bytes exceeds a notification")
        if size + n > room:
            out.append(head + ",".join(parts) + "]}")
            parts, size = [], 0
            n = len(text.encode())
        parts.append(text)
        size += n
    if parts:
        out.append(head + ",".join(parts) + "]}")
    return out


class Fanout:
    """Publish and receive JSON messages on named channels between processes (see module).

    `subscribe(channel, handler)` before `start`; handlers run in the listener thread, must be
    quick and must not raise (an exception is logged and the message dropped). `publish` may be
    called from any thread.
    """

    def __init__(self, database_url: str, *, origin: str | None = None) -> None:
        self._conninfo = conninfo(database_url)
        self.origin = origin or uuid.uuid4().hex[:12]
        # What pg_stat_activity shows of the listening connection.
        self.listener_name = f"intspace-fanout:{os.getpid()}:{self.origin}"
        self._handlers: dict[str, Handler] = {}
        self._on_reconnect: list[Callable[[], None]] = []
        self._listening = threading.Event()
        self._runner = LoopThread(self._listen, "fanout", join_timeout=5)
        self._pub_lock = threading.Lock()
        self._pub: psycopg.Connection[Any] | None = None
        self.received = 0
        self.published = 0
        self.errors = 0

    def subscribe(self, channel: str, handler: Handler) -> None:
        """Call `handler(message)` for every message another process publishes on `channel`."""
        if self._runner.started:
            raise RuntimeError("subscribe before start")
        self._handlers[channel] = handler

    def on_reconnect(self, callback: Callable[[], None]) -> None:
        """Call `callback()` (listener thread) each time the listener connects again after
        losing its connection: messages sent meanwhile were lost."""
        self._on_reconnect.append(callback)

    @property
    def listening(self) -> bool:
        """Whether the listener is connected and listening."""
        return self._listening.is_set()

    def start(self, timeout: float = 5.0) -> None:
        """Start the listener thread and wait up to `timeout` s until it listens."""
        self._runner.start()
        if not self._listening.wait(timeout):
            log.warning("fan-out: not listening after %.1f s; retrying in the background", timeout)

    def stop(self) -> None:
        """Stop listening and close both connections."""
        self._runner.stop()
        with self._pub_lock:
            if self._pub is not None:
                self._pub.close()
                self._pub = None

    # -- publishing ------------------------------------------------------------------------------

    def publish(self, channel: str, base: dict[str, Any], items: Sequence[Any]) -> int:
        """Send `items` on `channel` to the other processes, in as many notifications as the
        payload limit needs (each {**base, "o": origin, "items": [...]}); return how many were
        sent. A failure is logged and counted (the receivers catch up from the database)."""
        if not items:
            return 0
        texts = chunk_payloads({**base, "o": self.origin}, items)
        with self._pub_lock:
            try:
                if self._pub is None or self._pub.closed:
                    self._pub = psycopg.connect(self._conninfo, autocommit=True)
                # One round trip for every chunk.
                self._pub.execute(
                    "SELECT pg_notify(%s, p) FROM unnest(%s::text[]) WITH ORDINALITY AS m(p, k) "
                    "ORDER BY k",
                    (channel, texts),
                )
            except psycopg.Error as exc:
                self.errors += 1
                log.warning("fan-out: publishing on %s failed: %s", channel, exc)
                if self._pub is not None:
                    self._pub.close()
                    self._pub = None
                return 0
        self.published += len(texts)
        return len(texts)

    # -- listening -------------------------------------------------------------------------------

    def _listen(self) -> None:
        attempt = 0
        while not self._runner.stopping:
            try:
                with psycopg.connect(
                    self._conninfo, autocommit=True, application_name=self.listener_name
                ) as conn:
                    for channel in self._handlers:
                        conn.execute(sql.SQL("LISTEN {}").format(sql.Identifier(channel)))
                    self._listening.set()
                    if attempt:
                        log.info("fan-out: listening again")
                        for callback in self._on_reconnect:
                            self._call(callback)
                    attempt = 0
                    while not self._runner.stopping:
                        for note in conn.notifies(timeout=_POLL_S):
                            self._dispatch(note.channel, note.payload)
            except psycopg.Error as exc:
                self._listening.clear()
                delay = _BACKOFF_S[min(attempt, len(_BACKOFF_S) - 1)]
                attempt += 1
                log.warning("fan-out: listener lost (%s); reconnecting in %.1f s", exc, delay)
                self._runner.wait(delay)
        self._listening.clear()

    def _dispatch(self, channel: str, payload: str) -> None:
        handler = self._handlers.get(channel)
        if handler is None:
            return
        try:
            message = json.loads(payload)
        except ValueError:
            log.warning("fan-out: a message on %s is not JSON; dropped", channel)
            return
        if not isinstance(message, dict) or message.get("o") == self.origin:
            return
        self.received += 1
        self._call(handler, message)

    def _call(self, fn: Callable[..., None], *args: Any) -> None:
        try:
            fn(*args)
        except Exception:
            self.errors += 1
            log.exception("fan-out: a handler failed")
