"""What the home hears (spec 09): zones' occupancy, events, targets and cameras' health over
MQTT, with Home Assistant's MQTT discovery.

`HomePublisher` is a sink of the zones service (server.services.zones.HomeSink): it turns
definitions, occupancy changes, events and target updates into topics and payloads and hands
them to an `MqttLink` (server.services.comms.mqtt), which never blocks. Topics (slugs of names):

    <prefix>/available                       online / offline (last will), retained
    <prefix>/<space>/zones/<zone>/occupancy  people counted, retained
    <prefix>/<space>/events                  {"type", "target", "kind", "zone", "xy", "t"}
    <prefix>/<space>/targets/<id>            {"kind", "xy", "cov", "t", "state"}
    <prefix>/<space>/cameras/<camera>/health the camera's health (spec 08), retained

and per zone a Home Assistant occupancy `binary_sensor` and a people-count `sensor`, per camera
a connectivity `binary_sensor`, under `<discovery prefix>/<component>/intspace_<space id>/
<object id>/config` (retained; an empty retained config removes the entity), grouped in one
device per space. Renaming a space, zone or camera moves its topics and clears the old ones;
deleting a zone or camera clears its topics and removes its entities.

With several service processes (PostgreSQL), each publishes the spaces whose tracker it runs
(the zones service only calls it for those); `<prefix>/available` and its last will belong to
one process at a time (`available_owner`): the one holding the availability's advisory lock
(server.services.ownership, key AVAILABLE_KEY), which every process tries for each second, as
for a space's tracker. So the home hears `offline` only when no process serves:

* a clean stop of the owner hands the topic over: it gives up the lock and, when another
  intspace process is connected to the database, waits up to HANDOVER_S for one to take it,
  then leaves without a word (the retained `online` stands, and the new owner says it again
  under its own last will); only the last process says `offline`;
* a crashed owner's last will says `offline`, and the process that takes the lock over says
  `online` within a second or two; a last will that reaches the broker after that (a peer
  whose connection the broker notices late) is answered by the owner, which subscribes to the
  topic, with `online` again.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import select, text
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from core.localization.tracking import TrackSnapshot
from core.localization.zones import ZoneEvent
from server.db.models import Camera
from server.services._loop_thread import LoopThread
from server.services.comms.mqtt import Message, MqttLink
from server.services.ownership import APPLICATION_NAME, NAMESPACE
from server.services.zones import ZoneDef, slugify
from server.version import VERSION

log = logging.getLogger(__name__)

# How often the cameras' health is read (s), and the longest a retained health goes unrefreshed.
_HEALTH_POLL_S = 1.0
_HEALTH_REFRESH_S = 30.0
# Target rate limits remembered at most for this many targets (ended ones are forgotten at
# their end event; this bounds a tracker whose ends never come).
_MAX_RATE_ENTRIES = 10_000

ONLINE, OFFLINE = "online", "offline"
# The advisory lock key (server.services.ownership's namespace) of the availability topic:
# space ids are positive, so no space's tracker lock is this one.
AVAILABLE_KEY = -1
# How long a stopping owner waits for another process to take the availability over (s): the
# others try for its lock every _HEALTH_POLL_S.
HANDOVER_S = 3.0 * _HEALTH_POLL_S


def space_slug(space_id: int, name: str) -> str:
    """Return a space's topic slug: its name's, "space-<id>" when the name has none."""
    return slugify(name) or f"space-{space_id}"


def camera_slug(camera_id: int, name: str) -> str:
    """Return a camera's topic slug: its name's, "camera-<id>" when the name has none."""
    return slugify(name) or f"camera-{camera_id}"


@dataclass
class _Space:
    slug: str
    name: str
    zones: dict[tuple[str, int], ZoneDef] = field(default_factory=dict)
    # camera id -> (slug, name, last health JSON, when it was last retained)
    cameras: dict[int, tuple[str, str, str, float]] = field(default_factory=dict)


class HomePublisher:
    """Topics and Home Assistant discovery of the spaces tracked here (module docstring).

    health_of(camera id) returns a camera's health as a JSON-able dict with a "status" of
    online, stalled or offline. owns(space id) says whether this process runs the space's
    tracker (its cameras' health is published here then).
    """

    def __init__(
        self,
        link: MqttLink,
        *,
        prefix: str = "intspace",
        discovery_prefix: str = "homeassistant",
        target_hz: float = 2.0,
        factory: sessionmaker[Session] | None = None,
        health_of: Callable[[int], dict[str, Any]] | None = None,
        owns: Callable[[int | None], bool] = lambda _: True,
        available_lock: Any = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.link = link
        self.prefix = prefix.strip("/")
        self.discovery_prefix = discovery_prefix.strip("/")
        self._min_dt = 1.0 / target_hz if target_hz > 0 else None
        self._factory = factory
        self._health_of = health_of
        self._owns = owns
        self._clock = clock
        self._lock = threading.RLock()
        self._spaces: dict[int, _Space] = {}
        self._last_target: dict[tuple[int, int], float] = {}
        self.events = 0
        # Several processes: who publishes <prefix>/available (a SpaceLocks on key
        # AVAILABLE_KEY); one process alone always does.
        self._available_lock = available_lock
        self.available_owner = available_lock is None
        self._runner = LoopThread(self._loop, "home-cameras", join_timeout=5)

    @property
    def available_topic(self) -> str:
        """The availability topic of every entity."""
        return f"{self.prefix}/available"

    # -- topics -------------------------------------------------------------------------------

    def occupancy_topic(self, space: str, zone: str) -> str:
        return f"{self.prefix}/{space}/zones/{zone}/occupancy"

    def events_topic(self, space: str) -> str:
        return f"{self.prefix}/{space}/events"

    def target_topic(self, space: str, target: int) -> str:
        return f"{self.prefix}/{space}/targets/{target}"

    def health_topic(self, space: str, camera: str) -> str:
        return f"{self.prefix}/{space}/cameras/{camera}/health"

    def discovery_topic(self, component: str, space_id: int, object_id: str) -> str:
        return f"{self.discovery_prefix}/{component}/intspace_{space_id}/{object_id}/config"

    def _device(self, space_id: int, name: str) -> dict[str, Any]:
        return {
            "identifiers": [f"intspace_space_{space_id}"],
            "name": f"intspace {name}",
            "manufacturer": "intspace",
            "model": "intelligent space",
            "sw_version": VERSION,
        }

    def zone_discovery(self, space_id: int, space: _Space, zone: ZoneDef) -> dict[str, str]:
        """Return {discovery topic: config JSON} of a zone's two entities."""
        state = self.occupancy_topic(space.slug, zone.slug)
        base = {
            "state_topic": state,
            "availability_topic": self.available_topic,
            "payload_available": ONLINE,
            "payload_not_available": OFFLINE,
            "device": self._device(space_id, space.name),
        }
        oid = zone.object_id
        occupancy = {
            **base,
            "name": f"{zone.name} occupancy",
            "unique_id": f"intspace_{space_id}_zone_{oid}_occupancy",
            "device_class": "occupancy",
            "value_template": "{{ 'ON' if value | int > 0 else 'OFF' }}",
            "payload_on": "ON",
            "payload_off": "OFF",
        }
        count = {
            **base,
            "name": f"{zone.name} people",
            "unique_id": f"intspace_{space_id}_zone_{oid}_count",
            "unit_of_measurement": "people",
            "state_class": "measurement",
            "icon": "mdi:account-multiple",
        }
        return {
            self.discovery_topic("binary_sensor", space_id, f"zone_{oid}_occupancy"): json.dumps(
                occupancy
            ),
            self.discovery_topic("sensor", space_id, f"zone_{oid}_count"): json.dumps(count),
        }

    def camera_discovery(
        self, space_id: int, space: _Space, camera_id: int, slug: str, name: str
    ) -> dict[str, str]:
        """Return {discovery topic: config JSON} of a camera's connectivity entity."""
        config = {
            "name": f"{name} connectivity",
            "unique_id": f"intspace_{space_id}_camera_{camera_id}_connectivity",
            "state_topic": self.health_topic(space.slug, slug),
            "value_template": "{{ 'ON' if value_json.status == 'online' else 'OFF' }}",
            "payload_on": "ON",
            "payload_off": "OFF",
            "device_class": "connectivity",
            "json_attributes_topic": self.health_topic(space.slug, slug),
            "availability_topic": self.available_topic,
            "payload_available": ONLINE,
            "payload_not_available": OFFLINE,
            "device": self._device(space_id, space.name),
        }
        return {
            self.discovery_topic("binary_sensor", space_id, f"camera_{camera_id}_connectivity"): (
                json.dumps(config)
            )
        }

    # -- the zones' sink ----------------------------------------------------------------------

    def zones_defined(self, space_id: int, space_name: str, zones: Sequence[ZoneDef]) -> None:
        """Publish a space's zone entities; clear the topics of zones gone or renamed (and of
        everything of the space when the space was renamed)."""
        with self._lock:
            slug = space_slug(space_id, space_name)
            old = self._spaces.get(space_id)
            new = _Space(slug, space_name, {z.key: z for z in zones})
            if old is not None:
                new.cameras = old.cameras
                for key, zone in old.zones.items():
                    now = new.zones.get(key)
                    if now is None or now.slug != zone.slug or slug != old.slug:
                        self.link.retain(self.occupancy_topic(old.slug, zone.slug), b"")
                    if now is None:
                        for topic in self.zone_discovery(space_id, old, zone):
                            self.link.retain(topic, b"")
                if slug != old.slug or space_name != old.name:
                    for cid, (cslug, cname, _, _) in list(old.cameras.items()):
                        self.link.retain(self.health_topic(old.slug, cslug), b"")
                        new.cameras[cid] = (cslug, cname, "", 0.0)
            self._spaces[space_id] = new
            for zone in new.zones.values():
                for topic, config in self.zone_discovery(space_id, new, zone).items():
                    self.link.retain(topic, config)
                if self.link.retained(self.occupancy_topic(slug, zone.slug)) in (None, b""):
                    # A new zone says 0 at once; its count follows when it changes.
                    self.link.retain(self.occupancy_topic(slug, zone.slug), "0")
            for cid, (cslug, cname, _, _) in new.cameras.items():
                for topic, config in self.camera_discovery(
                    space_id, new, cid, cslug, cname
                ).items():
                    self.link.retain(topic, config)

    def occupancy(self, space_id: int, zone: ZoneDef, count: int) -> None:
        """Publish a zone's occupancy (retained)."""
        with self._lock:
            space = self._spaces.get(space_id)
            if space is None:
                return
            self.link.retain(self.occupancy_topic(space.slug, zone.slug), str(int(count)))

    def event(self, space_id: int, zone: ZoneDef | None, event: ZoneEvent) -> None:
        """Publish an event (not retained)."""
        with self._lock:
            space = self._spaces.get(space_id)
            if event.type == "end":
                self._last_target.pop((space_id, event.target), None)
            if space is None:
                return
            payload = {
                "type": event.type,
                "target": event.target,
                "kind": event.kind,
                "zone": None if zone is None else zone.slug,
                "xy": [round(event.xy[0], 4), round(event.xy[1], 4)],
                "t": event.t,
            }
            self.events += 1
            self.link.publish(self.events_topic(space.slug), json.dumps(payload), qos=1)

    def target(self, space_id: int, snap: TrackSnapshot) -> None:
        """Publish a live target's state, at most target_hz a second per target (by its
        capture times)."""
        if self._min_dt is None:
            return
        with self._lock:
            space = self._spaces.get(space_id)
            if space is None:
                return
            key = (space_id, snap.id)
            last = self._last_target.get(key)
            if last is not None and snap.t - last < self._min_dt:
                return
            if last is None and len(self._last_target) >= _MAX_RATE_ENTRIES:
                oldest = sorted(self._last_target.items(), key=lambda kv: kv[1])
                for k, _ in oldest[: _MAX_RATE_ENTRIES // 10]:
                    del self._last_target[k]
            self._last_target[key] = snap.t
            payload = {
                "kind": snap.kind,
                "xy": [round(float(snap.x[0]), 4), round(float(snap.x[1]), 4)],
                "cov": [[round(float(c), 8) for c in row] for row in snap.xy_cov],
                "t": snap.t,
                "state": str(snap.state),
            }
            self.link.publish(self.target_topic(space.slug, snap.id), json.dumps(payload))

    def forget_space(self, space_id: int) -> None:
        """Stop publishing a space (another process tracks it now, or it was deleted)."""
        with self._lock:
            self._spaces.pop(space_id, None)
            for key in [k for k in self._last_target if k[0] == space_id]:
                del self._last_target[key]

    def rate_entries(self) -> int:
        """Return how many targets' publishing times are remembered."""
        with self._lock:
            return len(self._last_target)

    # -- cameras' health ----------------------------------------------------------------------

    def refresh_cameras(self) -> None:
        """Read the cameras of the spaces published here; publish their health when it changed
        (or every _HEALTH_REFRESH_S), their entities when new, and clear those gone."""
        if self._factory is None or self._health_of is None:
            return
        with self._factory() as session:
            rows = session.execute(select(Camera.id, Camera.name, Camera.space_id)).all()
        now = self._clock()
        with self._lock:
            by_space: dict[int, dict[int, str]] = {}
            for cid, name, sid in rows:
                if sid is not None:
                    by_space.setdefault(sid, {})[cid] = name
            for space_id, space in self._spaces.items():
                present = by_space.get(space_id, {})
                for cid, (cslug, cname, _, _) in list(space.cameras.items()):
                    if cid not in present or camera_slug(cid, present[cid]) != cslug:
                        self.link.retain(self.health_topic(space.slug, cslug), b"")
                        if cid not in present:
                            for topic in self.camera_discovery(space_id, space, cid, cslug, cname):
                                self.link.retain(topic, b"")
                        del space.cameras[cid]
                for cid, name in present.items():
                    slug = camera_slug(cid, name)
                    _, _, last_json, last_t = space.cameras.get(cid, (slug, name, "", 0.0))
                    if cid not in space.cameras or space.cameras[cid][1] != name:
                        for topic, config in self.camera_discovery(
                            space_id, space, cid, slug, name
                        ).items():
                            self.link.retain(topic, config)
                    health = self._health_of(cid)
                    text = json.dumps(health, sort_keys=True)
                    status_changed = not last_json or (
                        json.loads(last_json).get("status") != health.get("status")
                    )
                    if status_changed or now - last_t >= _HEALTH_REFRESH_S:
                        self.link.retain(self.health_topic(space.slug, slug), text)
                        last_json, last_t = text, now
                    space.cameras[cid] = (slug, name, last_json, last_t)

    def claim_available(self) -> None:
        """Try for (or check) the availability topic's lock: its holder sets the last will and
        says online; a holder that lost it stops speaking for the others."""
        if self._available_lock is None:
            return
        self._available_lock.poll([AVAILABLE_KEY])
        owner = self._available_lock.holds(AVAILABLE_KEY)
        if owner and not self.available_owner:
            log.info("MQTT: this process publishes %s", self.available_topic)
            self.link.set_will((self.available_topic, OFFLINE))
            self.link.retain(self.available_topic, ONLINE)
        elif not owner and self.available_owner:
            self.link.set_will(None)
        self.available_owner = owner

    def start(self) -> None:
        """Start the link and the thread that publishes the cameras' health."""
        if self._available_lock is None:
            self.link.set_will((self.available_topic, OFFLINE))
            self.link.retain(self.available_topic, ONLINE)
        else:
            self.link.subscribe(self.available_topic, self._on_available)
            self.claim_available()
        self.link.start()
        self._runner.start()

    def _on_available(self, message: Message) -> None:
        """Another process's last will said `offline` while this one serves: say `online`."""
        if self.available_owner and not self._runner.stopping and message.payload == b"offline":
            log.info("MQTT: %s said offline by a last will; this process serves", message.topic)
            self.link.resend(self.available_topic)

    def _loop(self) -> None:
        while not self._runner.wait(_HEALTH_POLL_S):
            try:
                self.claim_available()
                self.refresh_cameras()
            except Exception:
                log.exception("publishing the cameras' health failed")

    def stop(self) -> None:
        """Stop: the availability topic's owner hands it over to another process, or, the last
        one, publishes `offline` (module docstring)."""
        self._runner.stop()
        final = [(self.available_topic, OFFLINE)] if self.available_owner else []
        if self._available_lock is not None:
            if self.available_owner:
                self.available_owner = False
                self._available_lock.release(AVAILABLE_KEY)
                if self._taken_over():
                    log.info("MQTT: %s handed over to another process", self.available_topic)
                    final = []
            self._available_lock.close()
        self.link.stop(final=final)

    def _taken_over(self) -> bool:
        """Return whether another process took the availability's lock within HANDOVER_S
        (at once False when no other intspace process is connected to the database)."""
        if self._factory is None:
            return False
        own = f"{APPLICATION_NAME}:{os.getpid()}"
        others = text(
            "SELECT count(*) FROM pg_stat_activity WHERE datname = current_database() "
            "AND application_name LIKE :pattern AND application_name <> :own"
        )
        held = text(
            "SELECT count(*) FROM pg_locks WHERE locktype = 'advisory' AND classid = :ns "
            "AND objid = :key AND objsubid = 2 AND granted AND database = "
            "(SELECT oid FROM pg_database WHERE datname = current_database())"
        )
        deadline = time.monotonic() + HANDOVER_S
        try:
            with self._factory() as session:
                if not session.scalar(others, {"pattern": f"{APPLICATION_NAME}:%", "own": own}):
                    return False
                key = AVAILABLE_KEY & 0xFFFFFFFF  # pg_locks shows the int4 key as an oid
                while time.monotonic() < deadline:
                    if session.scalar(held, {"ns": NAMESPACE, "key": key}):
                        return True
                    session.rollback()  # a fresh snapshot for the next look
                    time.sleep(0.1)
        except SQLAlchemyError as exc:
            log.warning("MQTT: could not tell whether another process serves: %s", exc)
        return False
