"""One MQTT connection (aiomqtt) kept up in its own thread: retained states, a bounded queue of
messages, subscriptions, a last will, reconnection with back-off.

The callers (the tracker's thread, the API's threads) never wait on the broker: `retain` keeps
the latest payload of each retained topic (a dict, bounded by the number of topics), `publish`
appends to a bounded queue (the oldest message is dropped and counted when it is full), and
both only wake the connection's thread. That thread runs an asyncio loop of its own: connected,
it sends the retained topics changed since it last sent them, then the queue; on every
(re)connection it sends every retained topic again (the broker may have lost them). A broker
that goes away is tried again after 0.25 s, doubling to `max_backoff_s`. A clean `stop` sends
its final messages (the `offline` availability) before disconnecting; otherwise the broker
sends the last will.

The broker's URL (`mqtt://user:password@host:1883`, `mqtts://` for TLS) is a secret: only its
`redacted()` form (no password) is ever logged or shown, and connection errors are logged
with the password cut out.
"""

from __future__ import annotations

import asyncio
import logging
import ssl
import threading
import time
import uuid
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any
from urllib.parse import unquote, urlsplit

import aiomqtt

log = logging.getLogger(__name__)

_FIRST_BACKOFF_S = 0.25
# Messages sent per wake-up before the loop yields (so a flood does not starve the reader).
_BATCH = 500


class BrokerUrlError(ValueError):
    """A broker URL that cannot be used; its message never contains the password."""


@dataclass(frozen=True)
class BrokerUrl:
    """A broker's address: host, port, TLS or not, user and password (secret)."""

    host: str
    port: int
    tls: bool
    username: str | None = None
    password: str | None = None

    @classmethod
    def parse(cls, url: str) -> BrokerUrl:
        """Return the broker of `mqtt://[user[:password]@]host[:port]` (1883) or `mqtts://`
        (8883, TLS with the system's certificate authorities)."""
        try:
            parts = urlsplit(url.strip())
            port = parts.port
        except ValueError:
            raise BrokerUrlError("the broker URL is malformed (mqtt://user:pw@host:1883)") from None
        if parts.scheme not in ("mqtt", "mqtts"):
            raise BrokerUrlError(
                f"the broker URL must start with mqtt:// or mqtts://, not {parts.scheme!r}://"
            )
        if not parts.hostname:
            raise BrokerUrlError("the broker URL has no host (mqtt://user:pw@host:1883)")
        if parts.path not in ("", "/") or parts.query or parts.fragment:
            raise BrokerUrlError("the broker URL takes no path, query or fragment")
        tls = parts.scheme == "mqtts"
        return cls(
            host=parts.hostname,
            port=port or (8883 if tls else 1883),
            tls=tls,
            username=unquote(parts.username) if parts.username else None,
            password=unquote(parts.password) if parts.password is not None else None,
        )

    def redacted(self) -> str:
        """Return the URL with the password replaced by ***."""
        auth = ""
        if self.username is not None:
            auth = self.username + (":***" if self.password is not None else "") + "@"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'mqtts' if self.tls else 'mqtt'}://{auth}{host}:{self.port}"

    def scrub(self, text: str) -> str:
        """Return `text` with the password cut out."""
        return text.replace(self.password, "***") if self.password else text


@dataclass(frozen=True)
class Message:
    """A message received on a subscription."""

    topic: str
    payload: bytes


def _bytes(payload: bytes | str) -> bytes:
    return payload if isinstance(payload, bytes) else payload.encode()


class MqttLink:
    """A connection to one broker, run by its own thread (module docstring).

    will: (topic, payload) published retained by the broker when the connection is lost.
    subscriptions: topic filters subscribed on every connection; `on_message` is called on the
    connection's thread with each message (it must not block). queue_limit: the most
    non-retained messages waiting while the broker is slow or away.
    """

    def __init__(
        self,
        url: BrokerUrl,
        *,
        client_id: str | None = None,
        will: tuple[str, bytes | str] | None = None,
        subscriptions: Sequence[str] = (),
        on_message: Callable[[Message], None] | None = None,
        on_connect: Callable[[], None] | None = None,
        queue_limit: int = 10_000,
        max_backoff_s: float = 2.0,
        keepalive_s: int = 10,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.url = url
        self.client_id = client_id or f"intspace-{uuid.uuid4().hex[:12]}"
        self._will = will
        self._subscriptions = tuple(subscriptions)
        self._on_message = on_message
        self._handlers: list[tuple[str, Callable[[Message], None]]] = []
        self._on_connect = on_connect
        self.queue_limit = int(queue_limit)
        self._max_backoff = float(max_backoff_s)
        self._keepalive = int(keepalive_s)
        self._clock = clock
        self._lock = threading.Lock()
        self._retained: dict[str, bytes] = {}
        self._dirty: OrderedDict[str, None] = OrderedDict()
        self._queue: deque[tuple[str, bytes, int]] = deque()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake: asyncio.Event | None = None
        self._stopping = False
        self._reconnect = False
        self._final: list[tuple[str, bytes]] = []
        self._thread: threading.Thread | None = None
        self.connected = False
        self.since: float | None = None
        self.dropped = 0
        self.published = 0
        self.received = 0
        self.connections = 0
        self.last_error: str | None = None

    # -- from any thread ---------------------------------------------------------------------

    def retain(self, topic: str, payload: bytes | str) -> None:
        """Make `payload` the retained state of `topic` (b"": clear the topic); sent now when
        connected, and again on every reconnection while it is not b""."""
        data = _bytes(payload)
        with self._lock:
            if self._retained.get(topic) == data:
                return
            self._retained[topic] = data
            self._dirty[topic] = None
            self._dirty.move_to_end(topic)
        self._poke()

    def retained(self, topic: str) -> bytes | None:
        """Return the retained payload kept for `topic`, None when there is none."""
        with self._lock:
            return self._retained.get(topic)

    def retained_topics(self, prefix: str = "") -> list[str]:
        """Return the retained topics kept (with a non-empty payload) starting with `prefix`."""
        with self._lock:
            return [t for t, p in self._retained.items() if p and t.startswith(prefix)]

    def resend(self, topic: str) -> None:
        """Send the retained state kept for `topic` again (someone else changed it on the
        broker: another process's last will)."""
        with self._lock:
            if not self._retained.get(topic):
                return
            self._dirty[topic] = None
            self._dirty.move_to_end(topic)
        self._poke()

    def subscribe(self, topic_filter: str, handler: Callable[[Message], None]) -> None:
        """Subscribe to `topic_filter` on every connection from the next one on (call before
        `start`); its messages go to `handler` (on the connection's thread; it must not
        block) instead of `on_message`."""
        with self._lock:
            self._subscriptions = (*self._subscriptions, topic_filter)
            self._handlers.append((topic_filter, handler))

    def publish(self, topic: str, payload: bytes | str, qos: int = 0) -> bool:
        """Queue a non-retained message; return False when the queue was full (the oldest
        message was dropped to make room, and counted)."""
        with self._lock:
            full = len(self._queue) >= self.queue_limit
            if full:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append((topic, _bytes(payload), qos))
        self._poke()
        return not full

    def set_will(self, will: tuple[str, bytes | str] | None) -> None:
        """Change the last will: the connection is made again with it."""
        with self._lock:
            if will == self._will:
                return
            self._will = will
            self._reconnect = self.connected  # not connected: the next connection has it
        self._poke()

    def status(self) -> dict[str, Any]:
        """Return the connection's state: url (redacted), connected, since (Unix s: when it
        connected or was lost), dropped, queued, published, received, connections, error."""
        with self._lock:
            queued = len(self._queue)
            pending = len(self._dirty)
        return {
            "url": self.url.redacted(),
            "connected": self.connected,
            "since": self.since,
            "dropped": self.dropped,
            "queued": queued,
            "pending_retained": pending,
            "published": self.published,
            "received": self.received,
            "connections": self.connections,
            "last_error": self.last_error,
        }

    def start(self) -> None:
        """Start the connection's thread (it connects, and reconnects, on its own)."""
        ready = threading.Event()
        self._thread = threading.Thread(
            target=self._run_thread, args=(ready,), name="mqtt", daemon=True
        )
        self._thread.start()
        ready.wait(5)

    def stop(self, final: Sequence[tuple[str, bytes | str]] = (), timeout: float = 5.0) -> None:
        """Send what is queued and `final` (retained) when connected, disconnect, stop."""
        with self._lock:
            self._final = [(t, _bytes(p)) for t, p in final]
            self._stopping = True
        self._poke()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def _poke(self) -> None:
        loop, wake = self._loop, self._wake
        if loop is not None and wake is not None:
            try:
                loop.call_soon_threadsafe(wake.set)
            except RuntimeError:
                pass  # the loop has closed: stopping

    # -- the connection's thread -------------------------------------------------------------

    def _run_thread(self, ready: threading.Event) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        self._wake = asyncio.Event()
        ready.set()
        try:
            loop.run_until_complete(self._run())
        finally:
            self._loop = None
            loop.close()

    def _client(self) -> aiomqtt.Client:
        will = None
        if self._will is not None:
            will = aiomqtt.Will(self._will[0], _bytes(self._will[1]), qos=1, retain=True)
        tls_context = ssl.create_default_context() if self.url.tls else None
        return aiomqtt.Client(
            self.url.host,
            self.url.port,
            username=self.url.username,
            password=self.url.password,
            identifier=self.client_id,
            will=will,
            keepalive=self._keepalive,
            timeout=5.0,
            tls_context=tls_context,
        )

    async def _run(self) -> None:
        assert self._wake is not None
        backoff = _FIRST_BACKOFF_S
        while not self._stopping:
            try:
                async with self._client() as client:
                    self._set_connected(True)
                    backoff = _FIRST_BACKOFF_S
                    with self._lock:
                        # The broker may have lost them: every retained topic goes again.
                        self._dirty = OrderedDict.fromkeys(self._retained)
                    for topic in self._subscriptions:
                        await client.subscribe(topic, qos=1)
                    if self._on_connect is not None:
                        self._on_connect()
                    reader = asyncio.create_task(self._read(client))
                    writer = asyncio.create_task(self._write(client))
                    done, pending = await asyncio.wait(
                        {reader, writer}, return_when=asyncio.FIRST_COMPLETED
                    )
                    for task in pending:
                        task.cancel()
                    for task in done:
                        task.result()  # the connection's error, if any
                    if writer in done:
                        return  # a clean stop
                    raise aiomqtt.MqttError("the broker closed the connection")
            except aiomqtt.MqttError as exc:
                self.last_error = self.url.scrub(str(exc))
                if self.connected:
                    log.warning(
                        "MQTT %s: connection lost: %s", self.url.redacted(), self.last_error
                    )
                self._set_connected(False)
            except Exception as exc:  # a callback's bug must not end the connection for good
                self.last_error = self.url.scrub(f"{type(exc).__name__}: {exc}")
                log.error("MQTT %s: %s", self.url.redacted(), self.last_error)
                self._set_connected(False)
            if self._stopping:
                return
            try:
                await asyncio.wait_for(self._wake.wait(), backoff)
            except TimeoutError:
                pass
            self._wake.clear()
            backoff = min(backoff * 2.0, self._max_backoff)

    def _set_connected(self, up: bool) -> None:
        if up != self.connected or self.since is None:
            self.since = self._clock()
        if up:
            self.connections += 1
            log.info("MQTT %s: connected", self.url.redacted())
        self.connected = up

    async def _read(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            self.received += 1
            handler = next(
                (h for f, h in self._handlers if message.topic.matches(f)), self._on_message
            )
            if handler is None:
                continue
            payload = message.payload
            data = payload if isinstance(payload, bytes) else str(payload or "").encode()
            try:
                handler(Message(str(message.topic), data))
            except Exception:
                log.exception("MQTT: handling a message on %s failed", message.topic)

    async def _write(self, client: aiomqtt.Client) -> None:
        assert self._wake is not None
        while True:
            self._wake.clear()
            sent = await self._send_some(client)
            with self._lock:
                stopping = self._stopping and not self._dirty and not self._queue
                reconnect, self._reconnect = self._reconnect, False
            if reconnect and not stopping:
                raise aiomqtt.MqttError("connecting again with a new last will")
            if stopping:
                for topic, payload in self._final:
                    await client.publish(topic, payload, qos=1, retain=True)
                return
            if sent < _BATCH:
                await self._wake.wait()

    async def _send_some(self, client: aiomqtt.Client) -> int:
        sent = 0
        while sent < _BATCH:
            with self._lock:
                if self._dirty:
                    topic, _ = self._dirty.popitem(last=False)
                    payload = self._retained.get(topic)
                    if payload is None:
                        continue
                    retain, qos = True, 1
                elif self._queue:
                    topic, payload, qos = self._queue.popleft()
                    retain = False
                else:
                    return sent
            try:
                await client.publish(topic, payload, qos=qos, retain=retain)
            except aiomqtt.MqttError:
                with self._lock:
                    if retain:
                        self._dirty[topic] = None  # sent again once reconnected
                    else:
                        self._queue.appendleft((topic, payload, qos))
                raise
            if retain and not payload:
                with self._lock:
                    # A cleared topic is forgotten once the broker has it, unless set again.
                    if self._retained.get(topic) == b"" and topic not in self._dirty:
                        del self._retained[topic]
            self.published += 1
            sent += 1
        return sent
