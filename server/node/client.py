"""A camera node's side of the service's REST API: the camera's registry row, batched
detections with a bounded buffer, heartbeats, and the clock offset from every answer's Date."""

from __future__ import annotations

import email.utils
import logging
import math
import threading
import time
from collections import deque
from typing import Any

import httpx

from server.delays import StageDelays
from server.node.clock import ClockOffset

log = logging.getLogger("intspace.node")

# The service a node posts to unless told otherwise.
DEFAULT_API = "http://127.0.0.1:8000/api/v1"
# Detections posted at once, at most (the endpoint takes far more; small batches keep latency).
_BATCH = 500
# How long (s) an upload waits after the service failed before it tries again, at most.
_RETRY_MAX_S = 2.0
# The key marking a queued item as a frame without detections (never sent as such).
_EMPTY = "_empty"


def _seconds(text: str | None) -> float | None:
    """Return a header's Unix seconds, None when absent or not a finite number."""
    try:
        value = float(text) if text else None
    except ValueError:
        return None
    return value if value is not None and math.isfinite(value) else None


def api_url(url: str) -> str:
    """Return the service's API root for a URL a user gave (with or without /api/v1)."""
    url = url.rstrip("/")
    return url if url.endswith("/api/v1") else url + "/api/v1"


class NodeError(Exception):
    """A problem the node cannot run with (unknown camera, refused token): its message is
    the one line printed before exiting."""


class ServiceClient:
    """The service at `api` (…/api/v1) with a bearer token; thread-safe."""

    def __init__(self, api: str, token: str, *, timeout: float = 5.0) -> None:
        self.api = api.rstrip("/")
        self.clock = ClockOffset()
        self._clock_lock = threading.Lock()
        # Whether an answer gave the service's time exactly: then whole-second Dates, which a
        # loaded service refreshes late, no longer count.
        self._precise = False
        self._http = httpx.Client(timeout=timeout, headers={"Authorization": f"Bearer {token}"})

    def close(self) -> None:
        """Close the connections."""
        self._http.close()

    def request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        """Send a request to `api + path`; measure the clock offset from its X-Server-Time
        header (every answer of the service), else from its Date header (another server)."""
        sent = time.time()
        response = self._http.request(method, self.api + path, **kwargs)
        received = time.time()
        precise = _seconds(response.headers.get("x-server-time"))
        if precise is not None:
            # The service says its time to the microsecond.
            with self._clock_lock:
                self._precise = True
                self.clock.add(sent, received, precise, precise)
            return response
        date = response.headers.get("date")
        if date and not self._precise:
            try:
                service = email.utils.parsedate_to_datetime(date).timestamp()
            except (TypeError, ValueError):
                return response
            # uvicorn refreshes its Date once a second: the service's time lay in [D, D + 2).
            with self._clock_lock:
                self.clock.add(sent, received, service, service + 2.0)
        return response

    @property
    def offset(self) -> float:
        """Return the clock offset (s) to add to the local clock to get the service's."""
        with self._clock_lock:
            return self.clock.offset

    def camera(self, name: str, space_id: int | None) -> dict[str, Any]:
        """Return the registry row of the camera called `name` (in space `space_id` when
        given). Raises NodeError when there is none, several, or the service refuses."""
        params: dict[str, Any] = {"name": name, "limit": 500}
        if space_id is not None:
            params["space_id"] = space_id
        try:
            response = self.request("GET", "/cameras", params=params)
            if response.status_code == 403:
                # An ingest token reads only its own cameras: look among those.
                items = self._own_cameras()
            elif response.status_code == 401:
                raise NodeError(
                    "the service refused the token (401); set INTSPACE_TOKEN to an ingest token "
                    "bound to this camera (or a token with the write scope)"
                )
            elif response.status_code != 200:
                raise NodeError(f"GET /cameras answered {response.status_code}: {response.text}")
            else:
                items = response.json()["items"]
        except httpx.TransportError as exc:
            raise NodeError(f"cannot reach the service at {self.api}: {exc}") from exc
        if space_id is not None:
            items = [row for row in items if row["space_id"] == space_id]
        rows = [row for row in items if row["name"] == name]
        where = f" in space {space_id}" if space_id is not None else ""
        if not rows:
            raise NodeError(
                f"the registry has no camera named {name!r}{where}; create it (POST "
                "/api/v1/cameras) or give the registry's name"
            )
        if len(rows) > 1:
            spaces = sorted({row["space_id"] for row in rows}, key=str)
            raise NodeError(
                f"{len(rows)} cameras are named {name!r} (spaces {spaces}); pick one with --space"
            )
        return rows[0]

    def _own_cameras(self) -> list[dict[str, Any]]:
        """Return the registry rows of the cameras an ingest token is bound to."""
        who = self.request("GET", "/session").json()
        ids = who.get("camera_ids")
        if not who.get("authenticated") or not ids:
            raise NodeError(
                f"the service refused the token (403: scopes {who.get('scopes')}); an ingest "
                "token finds its camera only when it is bound to it (POST /api/v1/tokens with "
                '"scopes": ["ingest"], "camera_ids": [...]), or use a token with the write scope'
            )
        rows = []
        for camera_id in ids:
            response = self.request("GET", f"/cameras/{camera_id}")
            if response.status_code == 200:
                rows.append(response.json())
        return rows

    def heartbeat(self, camera_id: int, body: dict[str, Any]) -> bool:
        """Report a camera's health; return whether the service took it."""
        try:
            response = self.request("POST", f"/cameras/{camera_id}/heartbeat", json=body)
        except httpx.TransportError:
            return False
        return response.status_code == 200


class Uploader:
    """Posts detections, and the camera frames in which nothing was detected, in small batches
    from a thread, in the order they were processed; keeps at most `capacity` while the
    service is unreachable, dropping the oldest (detections counted in `dropped`, empty frames
    in `dropped_empty`)."""

    def __init__(self, client: ServiceClient, capacity: int = 20_000) -> None:
        self._client = client
        self._queue: deque[dict[str, Any]] = deque()
        self._capacity = int(capacity)
        self._cond = threading.Condition()
        self._stop = False
        self.dropped = 0
        self.dropped_empty = 0
        self.rejected = 0
        self.posted = 0
        self.posted_empty = 0
        # Per camera frame posted: from its capture to the service's answer (s).
        self.delays = StageDelays(("capture to posted",))
        # Camera frames the service stored but could not track: they came after the tracker's
        # latency window (the node or the network too slow for INTSPACE_TRACKER_LATENCY_S).
        self.late = 0
        self._down_since: float | None = None
        self._thread = threading.Thread(target=self._run, name="uploader", daemon=True)

    def start(self) -> None:
        """Start posting."""
        self._thread.start()

    def stop(self, flush_s: float = 2.0) -> None:
        """Post what is queued (for at most `flush_s` s) and stop."""
        deadline = time.monotonic() + flush_s
        with self._cond:
            while self._queue and time.monotonic() < deadline and self._down_since is None:
                self._cond.wait(0.05)
            self._stop = True
            self._cond.notify_all()
        self._thread.join(flush_s + 6)

    def push(self, observations: list[dict[str, Any]]) -> None:
        """Queue one frame's detections."""
        if not observations:
            return
        with self._cond:
            self._queue.extend(observations)
            self._drop_over()
            self._cond.notify_all()

    def push_empty(self, camera_id: int, t: float) -> None:
        """Queue a frame of camera `camera_id` captured at `t` (service clock) in which nothing
        was detected: the service's tracker then need not wait for that camera up to t."""
        with self._cond:
            self._queue.append({_EMPTY: True, "camera_id": int(camera_id), "t": float(t)})
            self._drop_over()
            self._cond.notify_all()

    def _drop_over(self) -> None:
        """Drop the oldest queued items beyond the capacity, counted. Call with the lock held."""
        for _ in range(max(0, len(self._queue) - self._capacity)):
            if _EMPTY in self._queue.popleft():
                self.dropped_empty += 1
            else:
                self.dropped += 1

    @property
    def pending(self) -> int:
        """Return how many detections and empty frames wait to be posted."""
        with self._cond:
            return len(self._queue)

    def _run(self) -> None:
        wait = 0.1
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stop or bool(self._queue))
                if self._stop:
                    return
                batch = [self._queue.popleft() for _ in range(min(_BATCH, len(self._queue)))]
            ok = self._post(batch)
            with self._cond:
                if ok:
                    wait = 0.1
                    self._cond.notify_all()
                    continue
                # Back in front, in order; the capacity still holds (oldest dropped).
                self._queue.extendleft(reversed(batch))
                self._drop_over()
                self._cond.wait(wait)
                wait = min(2 * wait, _RETRY_MAX_S)

    def _post(self, batch: list[dict[str, Any]]) -> bool:
        """Post a batch; return False when it should be retried (service unreachable)."""
        observations = [o for o in batch if _EMPTY not in o]
        empty = [{"camera_id": o["camera_id"], "t": o["t"]} for o in batch if _EMPTY in o]
        body: dict[str, Any] = {"observations": observations}
        if empty:
            body["empty_frames"] = empty
        try:
            response = self._client.request("POST", "/observations", json=body)
        except httpx.TransportError as exc:
            self._down(f"cannot reach the service ({type(exc).__name__}); buffering")
            return False
        if response.status_code >= 500 or response.status_code == 429:
            self._down(f"the service answered {response.status_code}; buffering")
            return False
        if self._down_since is not None:
            log.warning(
                "service reachable again after %.1f s; %d detection(s) dropped so far",
                time.time() - self._down_since,
                self.dropped,
            )
            self._down_since = None
        if response.status_code != 200:
            # Bad input is not retried: the same batch would be refused again.
            self.rejected += len(observations)
            log.error(
                "the service refused %d detection(s) and %d empty frame(s): %s",
                len(observations),
                len(empty),
                response.text[:300],
            )
            return True
        self.posted += len(observations)
        self.posted_empty += len(empty)
        answered = time.time() + self._client.offset
        for _, t in {(o["camera_id"], o["t"]) for o in batch}:
            self.delays.add(answered - t)
        try:
            self.late += int(response.json().get("late", 0))
        except (ValueError, AttributeError):
            pass
        return True

    def _down(self, message: str) -> None:
        if self._down_since is None:
            self._down_since = time.time()
            log.warning(message)
