"""The service's clock on every answer: an `X-Server-Time` header (Unix seconds, microseconds).

A camera node stamps its frames on the service's clock (spec 08), measuring its offset from the
answers it gets. The Date header has whole seconds, so a node whose first answers carried only
Date stamped its first frames up to a second off and then jumped once POST /observations told it
the time precisely; with the header on every answer, the node's first request (the registry
look-up) already gives its offset to the round trip.
"""

from __future__ import annotations

import time

from starlette.types import Message, Receive, Scope, Send

from server.middleware import HttpMiddleware

SERVER_TIME_HEADER = "X-Server-Time"
_NAME = SERVER_TIME_HEADER.lower().encode("ascii")


class ServerTime(HttpMiddleware):
    """ASGI middleware adding X-Server-Time (the service's clock when the answer starts) to every
    HTTP response that does not set it itself."""

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:

        async def send_with_time(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                if all(name.lower() != _NAME for name, _ in headers):
                    headers.append((_NAME, f"{time.time():.6f}".encode("ascii")))
                    message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, send_with_time)
