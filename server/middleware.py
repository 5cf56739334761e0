"""What the service's ASGI middlewares share: each acts on HTTP requests only (a websocket or
lifespan message goes straight through to the app), and one that answers in place of the app
must know whether the app's answer has started going out."""

from __future__ import annotations

from abc import ABC, abstractmethod

from starlette.types import ASGIApp, Message, Receive, Scope, Send


class HttpMiddleware(ABC):
    """An ASGI middleware acting on HTTP requests only (`http`); anything else goes to `app`."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        await self.http(scope, receive, send)

    @abstractmethod
    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Handle one HTTP request."""


class StartWatch:
    """A `send` that passes every message on and notes whether the answer's start has gone out
    (`started`): after it, half an answer is out and no other can replace it."""

    def __init__(self, send: Send) -> None:
        self._send = send
        self.started = False

    async def __call__(self, message: Message) -> None:
        if message["type"] == "http.response.start":
            self.started = True
        await self._send(message)
