"""Frigate as a source (spec 09): the person boxes Frigate publishes on `frigate/events` become
the detections of intspace cameras, fed to the space's tracker through the same ingest as
`POST /observations` (TrackingService.ingest).

Frigate reports changes, not frames. It publishes an object's `new` once its own tracker has
confirmed it (no longer a false positive), an `update` when its path grows (current code), on
a zone change, a change between active and stationary, a better snapshot (at most every 5 s),
or at least once a minute, and an `end` when the object is gone; for a person standing still it
says nothing for up to a minute. The asynchronous EKF
(core.localization.tracking), the only tracker, confirms a track from several detections
within a second and lets a track coast and end within seconds without one. So, while Frigate
keeps an object (from its `new` to its `end`, or `timeout_s` without news), the box it last
reported is Frigate's standing claim: this source feeds, as one frame of the camera, every box
Frigate holds for that camera (a frame without one of them would tell the tracker that the
camera missed that person) at `hold_hz`, and at `burst_hz` for `burst_s` after an object's
`new` (after each report of an object Frigate publishes no path for, see below), so that the
tracker's confirmation sees what Frigate confirmed. What a held box says
grows vaguer with its age, by what Frigate's silence means:

* Frigate (its current code; the events carry `path_data`) publishes an update whenever an
  object's bottom centre moves PATH_STEP of the frame's diagonal from its path's last point:
  silence says the foot is still within that ellipse (in pixels, whatever the age). An active
  object's box is fed again only after PATH_QUIET_S without news: before, the walker is on
  the way to the next step, ahead of the box, and the tracker follows its own prediction. A Frigate
  whose paths grow by more than a point between two updates does not publish its steps: its
  paths bound nothing (`paths_published` turns False);
* an object Frigate called stationary may have shifted its box by STILL_SHIFT of its sides
  (more, and Frigate would have reported it moving);
* otherwise, the person may have walked V_WALK_M_S since the report; an active one past
  STALE_M is no longer fed.

The smaller bound is used. A stale box never holds a track where nobody is.

Each frame is stamped `lag` seconds in the past at most (the tracker's reorder latency, less a
fifth), never before what the camera already gave the tracker nor before what the tracker
already took: an update Frigate sends within that delay is still newer than every re-fed box,
and no frame is refused as late. Re-fed boxes are stored like the others (they are what the
tracker was given). Frigate's object ids are kept here for display only and never become a
target's label.

Each box (x0, y0, x1, y1, Frigate's detect pixels) is scaled to the intspace camera's image
size and measured as the observations API measures a box: core.localization.boxes.box_foot,
then foot_on_axis with the space's floor plan (the foot of the body's axis, from all four
edges, with its covariance), with the sides touching the detect frame's edge marked as cut; a
box that gives no floor position (a cut bottom, no standing body's) is not fed. Camera names
are looked up when events arrive (a camera registered later is picked up within
`_CAMERAS_TTL_S`).

Health: `frigate/stats` gives each camera's frame rate; the camera's health book gets a
heartbeat from it every second while the last stats are fresher than three of their periods.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from core.errors import IntspaceError
from core.localization import NetworkCamera
from core.localization.boxes import BOX_SIDES, FootMeasurement, box_foot, foot_on_axis
from core.localization.floor_spread import floor_spread_cov
from server.db.models import Camera
from server.services._loop_thread import LoopThread
from server.services.cameras import network_camera
from server.services.comms.mqtt import Message
from server.services.tracking import DetectionIn, TrackingService
from server.settings import FrigateCamera

log = logging.getLogger(__name__)

_CAMERAS_TTL_S = 5.0
_TICK_S = 0.05
# Messages waiting for the source's thread at most (a flood drops the oldest, counted).
_INBOX = 10_000
# Frigate's stats period when only one stats message was seen (its default, s).
_STATS_PERIOD_S = 60.0
# Without a published path, a re-fed box's foot is uncertain by the distance the person may
# have walked since Frigate's last report, at V_WALK_M_S from the report on (a box is never
# taken as exact after its frame: that would pin a walker's track where they were); the
# spread is isotropic on the floor (core.localization.floor_spread). Frigate reports a
# stationary object as soon as it moves out of its box, so the box of an object last reported
# stationary stands for as long as Frigate keeps it, within STILL_SHIFT below. The box of an
# object last reported active (moving) says less and less: its spread grows without
# bound, so after a second or so the tracker leaves it out (located_std, 0.5 m) and the track
# coasts until Frigate's next report (past STALE_M it is not fed at all). A stale box never
# holds a second track where the person was; a person who stops is held by the tracker's
# coasting until Frigate calls them stationary, after Frigate's `detect.stationary.threshold`
# frames (docs/home-automation.md advises about 2 s).
V_WALK_M_S = 1.0
# Frigate calls an object stationary while its box overlaps the box it stood in by an IoU of
# at least STILL_IOU (frigate/track/norfair_tracker.py resets the position below 0.6): two
# boxes of one size shifted by a fraction f of a side have the IoU (1 - f) / (1 + f), so the
# foot of a stationary object may be up to STILL_SHIFT of the box's width and height from
# where its box was.
STILL_IOU = 0.6
STILL_SHIFT = (1.0 - STILL_IOU) / (1.0 + STILL_IOU)
STALE_M = 1.0
# Frigate (its current code) adds a point to an object's path, and publishes an update, when its
# bottom centre moves this fraction of the detect frame's diagonal (frigate/track/
# tracked_object.py: 0.05 * sqrt(w^2 + h^2) / max(w, h) in coordinates normalised by w and h).
PATH_STEP = 0.05
# A walker reports a path step within this long (s): a step is 0.3-0.5 m at a ceiling camera's
# range, under a second at a walking pace. Until then an active object's last box is not fed
# again: it lies behind the walker, where another person may stand (a stale box on a standing
# person's spot pins the walker's track there, and the two tracks swap); after it, silence says
# the person slowed or stopped within the path step's ellipse, and the box is fed so.
PATH_QUIET_S = 1.0
# The cut mask this source builds, column by column (core's order).
assert BOX_SIDES == ("bottom", "top", "left", "right")


@dataclass
class _Held:
    """An object Frigate keeps: its intspace camera, its last box measured (the foot on the
    body's axis, in that camera's pixels, with its covariance; None when the box gives no
    floor position), when Frigate last said anything of it (service clock), the capture times
    of its last report and of its `new`, whether Frigate called it stationary, and, when
    Frigate publishes its path, the half-axes (px) of the ellipse around the path's last point
    that its foot has not left while Frigate stays silent."""

    frigate_id: str
    ref: _CameraRef
    pixel: np.ndarray | None
    cov: np.ndarray | None
    news: float
    report_t: float
    new_t: float
    stationary: bool = False
    path_bound: np.ndarray | None = None
    path_len: int = 0
    size: np.ndarray | None = None  # the box's width and height (px)


@dataclass(frozen=True)
class _CameraRef:
    id: int
    space_id: int | None
    width: int
    height: int
    camera: NetworkCamera | None  # None until calibrated (the tracker ignores it then too)


def _path_bound(
    path: object, box: np.ndarray, size: np.ndarray, detect: tuple[int, int]
) -> np.ndarray | None:
    """Return the half-axes (2,) px of the ellipse around a box's foot that the person's foot
    stays in while Frigate says nothing, from the `path_data` Frigate publishes (its list of
    ((x, y) normalised by the detect size, time) points): Frigate adds a point and publishes an
    update whenever the bottom centre moves PATH_STEP * diagonal / longer side (normalised)
    from the last point, so the foot is within that of the last point, itself this box's
    offset from the foot. None when the payload has no path (an older Frigate)."""
    if not isinstance(path, list) or not path:
        return None
    try:
        last = np.asarray(path[-1][0], dtype=np.float64).reshape(2)
    except (TypeError, ValueError, IndexError):
        return None
    if not np.all(np.isfinite(last)):
        return None
    dw, dh = detect
    step = PATH_STEP * float(np.hypot(dw, dh)) / max(dw, dh)
    foot = np.array([0.5 * (box[0] + box[2]), box[3]])
    return np.asarray((step + np.abs(foot / size - last)) * size, dtype=np.float64)


class FrigateSource:
    """Feeds Frigate's person boxes to the trackers (module docstring). Messages come from an
    MqttLink subscribed to `<topic_prefix>/events` and `<topic_prefix>/stats` (`on_message`,
    never blocking); a thread of its own feeds the tracker."""

    def __init__(
        self,
        factory: sessionmaker[Session],
        tracking: TrackingService,
        cameras: dict[str, FrigateCamera],
        *,
        labels: str = "person",
        timeout_s: float = 60.0,
        topic_prefix: str = "frigate",
        hold_hz: float = 4.0,
        burst_hz: float = 20.0,
        burst_s: float = 1.0,
        lag: float | None = None,
        heartbeat: Callable[[int, float, float | None], None] | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self._factory = factory
        self._tracking = tracking
        self._cameras = dict(cameras)
        self.labels = frozenset(s.strip() for s in labels.split(",") if s.strip())
        self.timeout_s = float(timeout_s)
        self.events_topic = f"{topic_prefix}/events"
        self.stats_topic = f"{topic_prefix}/stats"
        self._hold_dt = 1.0 / hold_hz
        self._burst_dt = 1.0 / burst_hz
        self._burst_s = float(burst_s)
        self.lag = tracking.latency if lag is None else float(lag)
        self._heartbeat = heartbeat
        self._clock = clock
        self._inbox: queue.Queue[Message] = queue.Queue(maxsize=_INBOX)
        self._lock = threading.Lock()
        self._held: dict[str, _Held] = {}
        # camera id -> the newest capture time fed: a camera's frames go in capture order.
        self._newest: dict[int, float] = {}
        self._refs: dict[str, tuple[float, _CameraRef | None]] = {}
        self._stats: dict[int, tuple[float, float]] = {}  # camera id -> (fps, received)
        self._stats_period = _STATS_PERIOD_S
        self._last_stats: float | None = None
        self._runner = LoopThread(self._loop, "frigate", join_timeout=5)
        # Whether this Frigate publishes an update at each step of an object's path (until an
        # update shows a path grown by more than one point since the last).
        self.paths_published = True
        # The connection it reads (for its status), set by whoever connects it.
        self.link: Any = None
        self.counts = {
            "events": 0,
            "fed": 0,
            "refed": 0,
            "late": 0,
            "ignored": 0,
            "unknown_camera": 0,
            "expired": 0,
            "dropped": 0,
            "errors": 0,
        }

    @property
    def subscriptions(self) -> tuple[str, str]:
        """The topics to subscribe to."""
        return (self.events_topic, self.stats_topic)

    # -- from the MQTT link's thread ----------------------------------------------------------

    def on_message(self, message: Message) -> None:
        """Queue a message for the source's thread (the oldest is dropped when it is full)."""
        while True:
            try:
                self._inbox.put_nowait(message)
                return
            except queue.Full:
                try:
                    self._inbox.get_nowait()
                    self.counts["dropped"] += 1
                except queue.Empty:
                    pass

    # -- the source's thread ------------------------------------------------------------------

    def start(self) -> None:
        """Start the thread."""
        self._runner.start()

    def stop(self) -> None:
        """Stop the thread (objects held are forgotten)."""
        self._runner.stop()

    def held(self) -> list[dict[str, Any]]:
        """Return the objects Frigate keeps, for display: Frigate's id, camera, last news."""
        with self._lock:
            return [
                {"frigate_id": h.frigate_id, "camera_id": h.ref.id, "news": h.news}
                for h in self._held.values()
            ]

    def status(self) -> dict[str, Any]:
        """Return the connection's state (redacted), the counters, the objects held and whether
        Frigate's paths bound its silence (`paths_published`)."""
        with self._lock:
            out: dict[str, Any] = {
                **self.counts,
                "held": len(self._held),
                "inbox": self._inbox.qsize(),
                "paths_published": self.paths_published,
            }
        if self.link is not None:
            out["broker"] = self.link.status()
        return out

    def _loop(self) -> None:
        last_beat = 0.0
        while not self._runner.stopping:
            try:
                message = self._inbox.get(timeout=_TICK_S)
            except queue.Empty:
                message = None
            try:
                if message is not None:
                    self.handle(message)
                    while True:  # everything waiting, then the hold
                        try:
                            self.handle(self._inbox.get_nowait())
                        except queue.Empty:
                            break
                self.hold()
                now = self._clock()
                if now - last_beat >= 1.0:
                    last_beat = now
                    self.beat_health()
            except Exception:
                self.counts["errors"] += 1
                log.exception("Frigate: handling a message failed")

    def handle(self, message: Message) -> None:
        """Handle one message of `frigate/events` or `frigate/stats`."""
        try:
            payload = json.loads(message.payload)
        except (ValueError, UnicodeDecodeError):
            self.counts["ignored"] += 1
            return
        if not isinstance(payload, dict):
            self.counts["ignored"] += 1
            return
        if message.topic == self.events_topic:
            self.counts["events"] += 1
            self._event(payload)
        elif message.topic == self.stats_topic:
            self._stats_message(payload)

    def _event(self, payload: dict[str, Any]) -> None:
        kind = payload.get("type")
        after = payload.get("after")
        if kind not in ("new", "update", "end") or not isinstance(after, dict):
            self.counts["ignored"] += 1
            return
        fid = str(after.get("id", ""))
        name = after.get("camera")
        if kind == "end" or after.get("false_positive") or after.get("label") not in self.labels:
            with self._lock:
                self._held.pop(fid, None)
            return
        config = self._cameras.get(str(name))
        if config is None:
            self.counts["ignored"] += 1
            return
        ref = self._camera(config.camera)
        if ref is None:
            self.counts["unknown_camera"] += 1
            return
        try:
            box = np.asarray(after["box"], dtype=np.float64).reshape(4)
            frame_time = float(after["frame_time"])
        except (KeyError, TypeError, ValueError):
            self.counts["ignored"] += 1
            return
        if not (np.all(np.isfinite(box)) and np.isfinite(frame_time)):
            self.counts["ignored"] += 1
            return
        dw, dh = config.detect
        # A side at the detect frame's edge is cut: the person may go on beyond it.
        edge = 1.0
        cut = np.array(
            [box[3] >= dh - edge, box[1] <= edge, box[0] <= edge, box[2] >= dw - edge], dtype=bool
        )
        size = np.array([ref.width, ref.height], dtype=np.float64)
        scaled = box * np.tile(size / np.array([dw, dh], dtype=np.float64), 2)
        try:
            pixel, cov = self._measure(ref, scaled, cut)
        except IntspaceError as exc:
            self.counts["ignored"] += 1
            log.debug("Frigate: box refused: %s", exc)
            return
        path = after.get("path_data")
        path_len = len(path) if isinstance(path, list) else 0
        now = self._clock()
        with self._lock:
            held = self._held.get(fid)
            if held is not None and path_len - held.path_len >= 2 and self.paths_published:
                # Points added between two updates: this Frigate does not publish its path's
                # steps (its path is only a record), so its silence bounds nothing.
                self.paths_published = False
                log.info("Frigate: paths grow between updates; held boxes age by walking")
            bound = _path_bound(path, scaled, size, (dw, dh)) if self.paths_published else None
            if held is None:
                held = _Held(fid, ref, pixel, cov, now, frame_time, frame_time)
                self._held[fid] = held
            else:
                held.ref, held.pixel, held.cov, held.news = ref, pixel, cov, now
                held.report_t = max(held.report_t, frame_time)
            held.stationary = bool(after.get("stationary", False))
            held.size = scaled[2:] - scaled[:2]
            held.path_bound = bound
            held.path_len = path_len
            view = [h for h in self._held.values() if h.ref.id == ref.id]
        self._feed_view(ref, self._stamp(ref, frame_time), view, fresh=held)
        self.counts["fed"] += 1

    def _measure(
        self, ref: _CameraRef, box: np.ndarray, cut: np.ndarray
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Return the foot on the body's axis of one box (camera pixels) and its covariance, as
        the observations API measures a box (core.localization.boxes: box_foot, then
        foot_on_axis with the space's floor plan); (None, None) when it gives no floor
        position (a cut bottom, a box no standing body makes, a camera not calibrated).
        Raises InvalidInput for a box that is not one."""
        foot = box_foot(box[None], cut[None])
        if ref.camera is None:
            return None, None
        axis = foot_on_axis(
            box[None],
            FootMeasurement(foot.pixel, foot.cov, foot.measured),
            ref.camera,
            cut=cut[None],
            occluders=self._tracking.floor_plan(ref.space_id),
        )
        if not (axis.measured[0] and np.all(np.isfinite(axis.cov[0]))):
            return None, None
        return axis.pixel[0], axis.cov[0]

    def hold(self) -> None:
        """Re-feed the boxes of the objects Frigate keeps (module docstring); forget those
        without news for timeout_s."""
        now = self._clock()
        with self._lock:
            for fid, h in list(self._held.items()):
                if now - h.news > self.timeout_s:
                    del self._held[fid]
                    self.counts["expired"] += 1
            by_camera: dict[int, list[_Held]] = {}
            for h in self._held.values():
                by_camera.setdefault(h.ref.id, []).append(h)
            for camera_id in [c for c in self._newest if c not in by_camera]:
                if now - self._newest[camera_id] > self.timeout_s:
                    del self._newest[camera_id]  # nothing held there for long: forgotten
        for held in by_camera.values():
            ref = held[0].ref
            # A fifth of the lag spare: the tracker's window moves on while this frame is
            # stored (a SQLite commit), and a frame behind it would be refused as late.
            stamp = self._stamp(ref, now - 0.8 * self.lag)
            # After a `new`, and after any report of an object Frigate gives no path for (its
            # reports are seconds apart: its track may have ended since the last one).
            burst = any(
                stamp - (h.new_t if h.path_bound is not None else h.report_t) < self._burst_s
                for h in held
            )
            dt = self._burst_dt if burst else self._hold_dt
            if stamp - self._newest.get(ref.id, -np.inf) >= dt:
                self.counts["refed"] += self._feed_view(ref, stamp, held)

    def _feed_view(
        self, ref: _CameraRef, t: float, held: list[_Held], fresh: _Held | None = None
    ) -> int:
        """Feed a camera frame at t of every box Frigate holds for that camera (a frame without
        one of them would tell the tracker the camera missed it), each uncertain by how far
        the person may be from it since its report (module docstring); return how many."""
        pixels, covs = [], []
        for h in held:
            if h.pixel is None or h.cov is None:
                continue
            spread = self._spread(ref, h, t)
            if h is not fresh and not h.stationary and self._walking(h, t):
                continue  # on its way to its next path step: no box says where it is now
            if spread is None:
                continue  # far vaguer than the tracker takes a detection: not fed
            pixels.append(h.pixel)
            covs.append(h.cov + spread)
        if pixels:
            self._feed(ref, t, np.stack(pixels), np.stack(covs))
        return len(pixels)

    def _walking(self, h: _Held, t: float) -> bool:
        """Whether an active object whose path Frigate publishes is, at t, taken to be walking
        to its next path step: within PATH_QUIET_S of its last report, and past the
        confirmation burst after its `new`."""
        return (
            h.path_bound is not None
            and t - h.report_t < PATH_QUIET_S
            and t - h.new_t >= self._burst_s
        )

    def _spread(self, ref: _CameraRef, h: _Held, t: float) -> np.ndarray | None:
        """Return the pixel covariance (2, 2) to add to a held box's foot at t: the smallest of
        the floor distance walked since its report (at V_WALK_M_S), for an object Frigate
        called stationary the shift its box may make and stay stationary (STILL_SHIFT of its
        width and height), and, when Frigate publishes its path, the ellipse its foot has not
        left (a uniform ellipse of half-axes a has the standard deviations a / 2); None when
        only the walk bounds it and it exceeds STALE_M."""
        walked = V_WALK_M_S * max(0.0, t - h.report_t)
        if walked <= 0.0:
            return np.zeros((2, 2))
        if ref.camera is None or h.pixel is None:
            return None
        bounds = []
        if h.path_bound is not None:
            bounds.append(np.diag((0.5 * h.path_bound) ** 2))
        if h.stationary and h.size is not None:
            bounds.append(np.diag((0.5 * STILL_SHIFT * h.size) ** 2))
        walk = floor_spread_cov(ref.camera, h.pixel[None], np.array([walked]))[0]
        if np.all(np.isfinite(walk)) and walked <= STALE_M:
            bounds.append(walk)
        return min(bounds, key=lambda c: float(np.trace(c)), default=None)

    def _stamp(self, ref: _CameraRef, t: float) -> float:
        """Return the capture time at which a box of Frigate's, reported at (or held until) t,
        reaches the tracker: t, or just after what the camera already gave the tracker and
        what the tracker already took. A camera's frames stay in capture order, and a Frigate
        box stands until Frigate says otherwise, so the later time is still true."""
        released = self._tracking.released(ref.space_id)
        floor = self._newest.get(ref.id, -np.inf)
        if released is not None:
            floor = max(floor, released)
        return max(t, floor + 1e-3)

    def _feed(self, ref: _CameraRef, t: float, pixels: np.ndarray, covs: np.ndarray) -> None:
        """Ingest a camera frame of measured feet: pixels (N, 2), covariances (N, 2, 2) px^2."""
        detections = [
            DetectionIn(
                camera_id=ref.id,
                t=t,
                pixel=(float(p[0]), float(p[1])),
                cov=((float(c[0, 0]), float(c[0, 1])), (float(c[1, 0]), float(c[1, 1]))),
                kind="person",
                height=0.0,  # the foot point is on the floor
            )
            for p, c in zip(pixels, covs, strict=True)
        ]
        with self._lock:
            self._newest[ref.id] = max(self._newest.get(ref.id, -np.inf), t)
        with self._factory() as session:
            result = self._tracking.ingest(session, detections, {ref.id: ref.space_id})
        self.counts["late"] += result.late

    def _camera(self, name: str) -> _CameraRef | None:
        now = time.monotonic()
        cached = self._refs.get(name)
        if cached is not None and now - cached[0] < _CAMERAS_TTL_S:
            return cached[1]
        with self._factory() as session:
            rows = session.scalars(select(Camera).where(Camera.name == name)).all()
        ref = None
        if len(rows) == 1:
            c = rows[0]
            cam: NetworkCamera | None
            try:
                cam = network_camera(c)
            except IntspaceError:  # not placed yet, or a model it cannot use
                cam = None
            ref = _CameraRef(c.id, c.space_id, c.width, c.height, cam)
        elif len(rows) > 1:
            log.warning("Frigate: %d cameras are called %r; none is fed", len(rows), name)
        self._refs[name] = (now, ref)
        return ref

    # -- health -------------------------------------------------------------------------------

    def _stats_message(self, payload: dict[str, Any]) -> None:
        now = self._clock()
        if self._last_stats is not None and now - self._last_stats > 0.5:
            self._stats_period = now - self._last_stats
        self._last_stats = now
        cameras = payload.get("cameras", payload)  # Frigate >= 0.14 nests them
        if not isinstance(cameras, dict):
            return
        for name, config in self._cameras.items():
            entry = cameras.get(name)
            if not isinstance(entry, dict):
                continue
            fps = entry.get("camera_fps")
            ref = self._camera(config.camera)
            if ref is None or not isinstance(fps, int | float) or not np.isfinite(fps):
                continue
            self._stats[ref.id] = (max(0.0, float(fps)), now)
        self.beat_health()

    def beat_health(self) -> None:
        """Give the health book a heartbeat of each Frigate camera whose stats are fresh."""
        if self._heartbeat is None:
            return
        now = self._clock()
        for camera_id, (fps, received) in list(self._stats.items()):
            if now - received > 3.0 * self._stats_period:
                del self._stats[camera_id]  # Frigate went quiet: the camera goes offline
                continue
            self._heartbeat(camera_id, fps, now if fps > 0 else None)
