"""The home hears the space (spec 09): the twin's rooms over MQTT against the twin's truth, the
capture-to-MQTT latency, and a long run faster than real time that must not pile anything up.

Run from the repository root (Debian's mosquitto is started on a free port):
    python -m bench.bench_mqtt [--seconds 120] [--soak-minutes 30] [--skip-frigate-soak]

Twin (real time, in process, as `intspace serve` runs it with INTSPACE_SIMULATION and
INTSPACE_MQTT_URL): the default home, its walker going from room to room, its rooms published
as zones. A subscriber records every message with its arrival time. Scored against the twin's
truth (for scoring only): the walker's true positions at the capture time of each twin instant
(GET /twin's mapping of capture time to simulated time) run through the same zone state machine
(core.localization.zones, inertia 1 s) give the true enter/leave events of each room; each
published event is paired with the true one of the same room and type nearest in time. Latency:
arrival minus the payload's `t` (the capture time of the detection that decided it) for every
event and target message; the anchor is spec 09's p95 <= 1 s.

Soak (faster than real time): the same service parts (tracking, zones, the MQTT publisher on a
real broker, live targets on a SQLite file) on a simulated clock, fed 30 simulated minutes of
the default home's five cameras seeing three walkers who come and go (each present 90 s of
every 120 s, standing still 20 s of it): first their feet projected with 0.7 px noise (2 frames
a second a camera by default: the tracker's arithmetic, not the clock, sets the pace), then
Frigate's events of the same walkers (tests/support/frigate_replay: `new`, an `update` per path
step, stationary change or snapshot, `end`) through the Frigate source as the service runs it.
Every simulated minute it records what could pile up: the MQTT queue and its drops, the targets
followed by the zones, the publisher's per-target rate entries, the live targets and the
tracker's tracks, the Frigate objects held and its inbox, and the Python heap (tracemalloc).
Nothing may grow with time: the last third's maxima must not exceed the first third's by more
than the noise of three walkers (printed).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import threading
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_ROOT))

from tests.support.mqtt_broker import Broker, subscribe  # noqa: E402

TOKEN = "bench-mqtt-admin-token"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}


def _migrated_sqlite(folder: Path) -> str:
    from alembic import command

    from server.db.migrate import alembic_config

    url = f"sqlite:///{folder / 'intspace.sqlite3'}"
    command.upgrade(alembic_config(url), "head")
    return url


def run_twin(broker: Broker, seconds: float) -> dict[str, float]:
    """Run the twin with MQTT on for `seconds`; return the scores."""
    from fastapi.testclient import TestClient

    from core.localization.zones import Zone, ZoneOccupancy
    from core.sim.motion import world_state
    from server.app import create_app
    from server.services.zones import slugify
    from server.settings import Settings

    folder = Path(tempfile.mkdtemp(prefix="bench-mqtt-"))
    settings = Settings(
        _env_file=None,
        database_url=_migrated_sqlite(folder),
        data_dir=folder,
        admin_token=TOKEN,
        viser_enabled=False,
        simulation=True,
        mqtt_url=broker.url,
    )
    sub, rec = subscribe(broker, ["intspace/#"])
    stamps: list[float] = []
    with TestClient(create_app(settings)) as client:
        twin = client.app.state.runtime.twin
        scene = twin.scene
        space = client.get(f"/api/v1/spaces/{twin.space_id}", headers=HEADERS).json()
        prefix = f"intspace/{slugify(space['name'])}"
        end = time.time() + seconds
        while time.time() < end:
            # Each twin instant's capture stamp (what its frames carry), for the truth.
            frame = twin.frame(next(iter(twin.camera_ids.values())))
            if frame is not None and (not stamps or frame.t > stamps[-1]):
                stamps.append(frame.t)
            time.sleep(0.05)
        sim_times = twin.sim_time_at(np.array(stamps))
        # Where the time goes before MQTT: the tracker's stages (capture to arrival holds the
        # twin's detection; then the reorder wait and the tracker's update).
        stages = client.app.state.runtime.tracking.delays.describe()
        steps = twin.steps
    sub.loop_stop()
    sub.disconnect()
    shutil.rmtree(folder, ignore_errors=True)

    # The truth: the walker's rooms through the same state machine (inertia 1 s).
    rooms = {slugify(r.name): np.array(r.polygon, dtype=np.float64) for r in scene.rooms}
    truth = ZoneOccupancy([Zone(k, p, inertia_s=1.0) for k, p in rooms.items()])
    true_events = []
    for stamp, s in zip(stamps, sim_times, strict=True):
        if not np.isfinite(s):
            continue
        for w, xy in enumerate(world_state(scene, float(s)).people):
            for e in truth.update(w + 1, "person", xy, stamp):
                if e.zone is not None:
                    true_events.append((e.type, e.zone, e.t))
    got = [
        (json.loads(p), t_arr) for t_arr, topic, p, _ in rec.messages if topic == f"{prefix}/events"
    ]
    est_events = [(e["type"], e["zone"], e["t"]) for e, _ in got if e["zone"] is not None]
    latency = [
        t_arr - json.loads(p)["t"]
        for t_arr, topic, p, _ in rec.messages
        if topic == f"{prefix}/events" or topic.startswith(f"{prefix}/targets/")
    ]
    lat = np.array(latency) if latency else np.array([np.nan])
    out = {
        "instants": len(stamps),
        **score_events(true_events, est_events),
        "latency messages": int(lat.size),
        "latency p50 s": float(np.nanpercentile(lat, 50)),
        "latency p95 s": float(np.nanpercentile(lat, 95)),
    }
    print("Twin over MQTT (real time):")
    for k, v in out.items():
        print(f"  {k:<28} {v:.3f}" if isinstance(v, float) else f"  {k:<28} {v}")
    print(f"  twin steps {steps} in {seconds:g} s ({steps / seconds:.1f} Hz of 5 asked)")
    print(f"  tracker stages: {stages}")
    print(f"  true events: {true_events}")
    print(f"  published:   {[(k, z, round(t, 2)) for k, z, t in est_events]}")
    print(f"  anchor: latency p95 <= 1 s -> {'met' if out['latency p95 s'] <= 1.0 else 'NOT met'}")
    return out


def score_events(true_events, est_events) -> dict[str, float]:
    """Pair each true (type, zone, t) with the published one of its zone and type nearest in
    time (within 3 s); return the counts and the median offset."""
    offsets = []
    missed = 0
    for kind, zone, t in true_events:
        cands = [abs(te - t) for k, z, te in est_events if k == kind and z == zone]
        if cands and min(cands) < 3.0:
            offsets.append(min(cands))
        else:
            missed += 1
    published = len([e for e in est_events if e[0] in ("enter", "leave")])
    return {
        "true enter/leave": len(true_events),
        "published enter/leave": published,
        "matched": len(offsets),
        "missed": missed,
        "extra": published - len(offsets),
        "event time offset median s": float(np.median(offsets)) if offsets else float("nan"),
    }


def run_light(broker: Broker, seconds: float, rate_hz: float = 5.0, seed: int = 0) -> None:
    """The twin's walker in real time without rendering: its true position projected into the
    home's registered cameras (0.7 px noise) at `rate_hz`, posted through the service's ingest
    with its threads running (tracker, zones, MQTT) as `intspace serve` runs them. Scores the
    rooms' events against the walker's truth and the capture-to-MQTT latency of every event
    and target message. What rendering and detecting add is the twin's (or a camera node's)
    own cost, measured by bench_end_to_end."""
    from core.localization.zones import Zone, ZoneOccupancy
    from core.sim import default_scene
    from core.sim.motion import world_state
    from server.db.session import make_engine, make_session_factory
    from server.services.cameras import registry_cameras
    from server.services.comms.home import HomePublisher
    from server.services.comms.mqtt import BrokerUrl, MqttLink
    from server.services.targets import LiveTargets
    from server.services.tracking import DetectionIn, TrackingService
    from server.services.twin_home import bootstrap_space
    from server.services.zones import ZoneService, slugify

    folder = Path(tempfile.mkdtemp(prefix="bench-mqtt-light-"))
    factory = make_session_factory(make_engine(_migrated_sqlite(folder)))
    scene = default_scene()
    with factory() as session:
        space_id, camera_ids = bootstrap_space(session, scene)
        cams, _ = registry_cameras(session, list(camera_ids.values()))
        from server.db.models import Space

        space_name = session.get(Space, space_id).name
    live = LiveTargets(factory)
    tracking = TrackingService(factory, live, latency=1.0)
    zones = ZoneService(factory, owns=tracking.owns)
    tracking.target_listeners.append(zones.on_targets)
    home = HomePublisher(MqttLink(BrokerUrl.parse(broker.url)), factory=factory)
    zones.sinks.append(home)
    sub, rec = subscribe(broker, ["intspace/#"])
    home.start()
    zones.start()
    live.start()
    tracking.start()
    prefix = f"intspace/{slugify(space_name)}"
    rng = np.random.default_rng(seed)
    rooms = {slugify(r.name): np.array(r.polygon, dtype=np.float64) for r in scene.rooms}
    truth = ZoneOccupancy([Zone(k, p, inertia_s=1.0) for k, p in rooms.items()])
    true_events = []
    t_start = time.time()
    k = 0
    while time.time() - t_start < seconds:
        t = t_start + k / rate_hz
        time.sleep(max(0.0, t - time.time()))
        sim = t - t_start
        people = world_state(scene, sim).people
        for w, xy in enumerate(people):
            for e in truth.update(w + 1, "person", xy, t):
                if e.zone is not None:
                    true_events.append((e.type, e.zone, e.t))
        P = np.array([[x, y, 1.0] for x, y in people])
        detections, empty = [], []
        for cid, cam in cams.items():
            seen = cam.in_view(P)
            for p in cam.project(P[seen]) + rng.normal(0, 0.7, (int(seen.sum()), 2)):
                detections.append(
                    DetectionIn(
                        cid,
                        t,
                        (float(p[0]), float(p[1])),
                        ((0.49, 0.0), (0.0, 0.49)),
                        "person",
                        1.0,
                    )
                )
            if not seen.any():
                empty.append((cid, t))
        with factory() as session:
            tracking.ingest(session, detections, dict.fromkeys(cams, space_id), empty=empty)
        k += 1
    time.sleep(3.0)
    stages = tracking.delays.describe()
    tracking.stop()
    zones.stop()
    home.stop()
    live.stop()
    sub.loop_stop()
    sub.disconnect()
    shutil.rmtree(folder, ignore_errors=True)
    est_events = [
        (e["type"], e["zone"], e["t"])
        for _, topic, p, _ in rec.messages
        if topic == f"{prefix}/events" and (e := json.loads(p))["zone"] is not None
    ]
    latency = np.array(
        [
            t_arr - json.loads(p)["t"]
            for t_arr, topic, p, _ in rec.messages
            if topic == f"{prefix}/events" or topic.startswith(f"{prefix}/targets/")
        ]
    )
    out = {"frames": k, **score_events(true_events, est_events)}
    out |= {
        "latency messages": int(latency.size),
        "latency p50 s": float(np.percentile(latency, 50)),
        "latency p95 s": float(np.percentile(latency, 95)),
    }
    print(
        f"Twin's walker over MQTT, no rendering (real time, {rate_hz:g} Hz x {len(cams)} cameras):"
    )
    for key, v in out.items():
        print(f"  {key:<28} {v:.3f}" if isinstance(v, float) else f"  {key:<28} {v}")
    print(f"  tracker stages: {stages}")
    print(f"  anchor: latency p95 <= 1 s -> {'met' if out['latency p95 s'] <= 1.0 else 'NOT met'}")


class _Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


class _SoakService:
    """The service's parts a soak runs (tracking, zones, the MQTT publisher on a real broker,
    live targets on a SQLite file) on a simulated clock, and what it records of them."""

    def __init__(self, broker: Broker, top: int) -> None:
        from core.sim import default_scene
        from server.db.session import make_engine, make_session_factory
        from server.services.cameras import registry_cameras
        from server.services.comms.home import HomePublisher
        from server.services.comms.mqtt import BrokerUrl, MqttLink
        from server.services.targets import LiveTargets
        from server.services.tracking import TrackingService
        from server.services.twin_home import bootstrap_space
        from server.services.zones import ZoneService

        self.folder = Path(tempfile.mkdtemp(prefix="bench-mqtt-soak-"))
        self.factory = make_session_factory(make_engine(_migrated_sqlite(self.folder)))
        with self.factory() as session:
            self.space_id, self.camera_ids = bootstrap_space(session, default_scene())
            self.cams, _ = registry_cameras(session, list(self.camera_ids.values()))
        self.clock = _Clock(time.time())
        self.live = LiveTargets(self.factory, track_retention_s=120.0, detection_retention_s=60.0)
        self.tracking = TrackingService(self.factory, self.live, latency=0.5, clock=self.clock)
        self.zones = ZoneService(self.factory, owns=self.tracking.owns)
        self.tracking.target_listeners.append(self.zones.on_targets)
        self.link = MqttLink(BrokerUrl.parse(broker.url), queue_limit=10_000)
        self.home = HomePublisher(self.link, factory=self.factory, target_hz=2.0)
        self.zones.sinks.append(self.home)
        self.home.start()
        self.zones.reload()
        self.sub, self.rec = subscribe(broker, ["intspace/#"])
        self.top = top
        self.rows: list[dict[str, float]] = []
        self.extra: Callable[[], dict[str, float]] = dict
        self._early = self._last = None
        tracemalloc.start()
        self._wall0 = time.perf_counter()

    def sample(self, minute: float) -> None:
        """Record, once a simulated minute, what could pile up."""
        self.live.flush()
        self.live.apply_retention(self.clock.t)
        status = self.link.status()
        # The service's heap: this bench's own subscriber (it keeps every message it received)
        # is left out; the tracker's record of its frames' delays (bounded at 20,000 frames) is
        # shown on its own.
        snap = tracemalloc.take_snapshot().filter_traces(
            [tracemalloc.Filter(False, "*mqtt_broker.py"), tracemalloc.Filter(False, "*paho*")]
        )
        heap = sum(st.size for st in snap.statistics("filename")) / 2**20
        if len(self.rows) == 2:
            self._early = snap
        if self.top and len(self.rows) >= 2:
            self._last = snap
        delays = sum(
            st.size
            for st in snap.filter_traces(
                [tracemalloc.Filter(True, "*server/delays.py")]
            ).statistics("filename")
        )
        if len(self.rows) == 1:
            print("  " + "  ".join(f"{k:>12}" for k in self.rows[0]), flush=True)
        if self.rows:
            print("  " + "  ".join(f"{v:>12.1f}" for v in self.rows[-1].values()), flush=True)
        self.rows.append(
            {
                "minute": minute,
                "queued": status["queued"],
                "dropped": status["dropped"],
                "zone targets": self.zones.followed(),
                "rate entries": self.home.rate_entries(),
                "live targets": len(self.live),
                "tracks": len(self.tracking.tracks(self.space_id)),
                "heap MiB": heap,
                "delays MiB": delays / 2**20,
                **self.extra(),
            }
        )

    def report(self, title: str, minutes: float) -> None:
        """Stop the parts and print the rows and the first and last thirds' maxima."""
        wall = time.perf_counter() - self._wall0
        rows = self.rows
        if self.top and self._last is not None and self._early is not None:
            print("  heap growth since minute 2, by line:")
            for stat in self._last.compare_to(self._early, "lineno")[: self.top]:
                print(f"    {stat}")
        time.sleep(2.0)
        final = self.link.status()
        self.home.stop()
        self.sub.loop_stop()
        self.sub.disconnect()
        tracemalloc.stop()
        shutil.rmtree(self.folder, ignore_errors=True)
        print(
            f"{title}: {minutes:g} simulated minutes in {wall:.0f} s of wall time "
            f"({minutes * 60 / wall:.1f}x real time), {len(self.cams)} cameras"
        )
        keys = list(rows[0])
        print("  " + "  ".join(f"{k:>12}" for k in keys))
        for r in rows:
            print("  " + "  ".join(f"{r[k]:>12.1f}" for k in keys))
        first = rows[1 : 1 + max(1, len(rows) // 3)] or rows
        last = rows[-max(1, len(rows) // 3) :]
        for key in keys[1:]:
            if key == "dropped":
                continue
            a = max(r[key] for r in first)
            b = max(r[key] for r in last)
            print(f"  {key:<14} first third max {a:8.1f}   last third max {b:8.1f}")
        events = sum(1 for _, t, _, _ in self.rec.messages if t.endswith("/events"))
        print(
            f"  MQTT: published {final['published']}, dropped {final['dropped']}, received by "
            f"the subscriber {len(self.rec.messages)} ({events} events)"
        )


def _walkers(seed: int) -> Callable[[float], np.ndarray]:
    """Three walkers in the default home who come and go (each present 90 s of every 120 s)
    and stand still 20 s of every 120 s; positions(s) is (3, 2), NaN for those absent."""
    rng = np.random.default_rng(seed)
    centre = np.array([[2.2, 3.0], [6.2, 1.5], [6.2, 4.5]])
    amp = np.array([[1.5, 2.0], [1.2, 1.0], [1.2, 1.0]])
    omega = rng.uniform(0.15, 0.3, (3, 2))
    phase = rng.uniform(0, 2 * np.pi, (3, 2))
    offset = 40.0 * np.arange(3)

    def positions(s: float) -> np.ndarray:
        cycle = (s + offset) % 120.0
        walked = (s + offset) // 120.0 * 100.0 + np.minimum(cycle, 30.0)
        walked += np.maximum(cycle - 50.0, 0.0)
        xy = centre + amp * np.sin(omega * walked[:, None] + phase)
        xy[cycle >= 90.0] = np.nan
        return xy

    return positions


def run_soak(
    broker: Broker, minutes: float, rate_hz: float = 5.0, seed: int = 0, top: int = 0
) -> None:
    """Feed `minutes` of simulated time of the walkers' projected feet as fast as it goes."""
    from server.services.tracking import DetectionIn

    svc = _SoakService(broker, top)
    positions = _walkers(seed)
    rng = np.random.default_rng(seed + 1)
    t0 = svc.clock.t
    dt = 1.0 / rate_hz
    steps = int(minutes * 60 * rate_hz)
    for k in range(steps):
        s = k * dt
        svc.clock.t = t0 + s
        xy = positions(s)
        xy = xy[~np.isnan(xy[:, 0])]
        P = np.column_stack([xy, np.full(len(xy), 1.0)])
        detections, empty = [], []
        for cid, cam in svc.cams.items():
            seen = cam.in_view(P) if len(P) else np.zeros(0, bool)
            px = (
                cam.project(P[seen]) + rng.normal(0, 0.7, (int(seen.sum()), 2))
                if seen.any()
                else []
            )
            for p in px:
                detections.append(
                    DetectionIn(
                        cid,
                        svc.clock.t,
                        (float(p[0]), float(p[1])),
                        ((0.49, 0.0), (0.0, 0.49)),
                        "person",
                        1.0,
                    )
                )
            if not len(px):
                empty.append((cid, svc.clock.t))
        with svc.factory() as session:
            svc.tracking.ingest(
                session, detections, dict.fromkeys(svc.cams, svc.space_id), empty=empty
            )
        svc.tracking.process(svc.clock.t + 0.01)
        if k % int(60 * rate_hz) == 0:
            svc.sample(s / 60.0)
    svc.report(f"Soak ({rate_hz:g} Hz a camera)", minutes)


def run_frigate_soak(broker: Broker, minutes: float, seed: int = 0, top: int = 0) -> None:
    """Feed `minutes` of simulated time of Frigate's events for the same walkers, seen by the
    home's cameras (Frigate's detect resolution half theirs), through the Frigate source as
    the service runs it, as fast as it goes. The source's thread is not started: its loop's
    work (every message due, then the hold) runs here at its tick on the simulated clock."""
    from server.services.comms.frigate import FrigateSource
    from server.services.comms.mqtt import Message
    from server.settings import FrigateCamera
    from tests.support.frigate_replay import frigate_messages

    svc = _SoakService(broker, top)
    names = {cid: name for name, cid in svc.camera_ids.items() if cid in svc.cams}
    mapping = {
        name: FrigateCamera(
            camera=name,
            detect=(svc.cams[cid].image_size[0] // 2, svc.cams[cid].image_size[1] // 2),
        )
        for cid, name in names.items()
    }
    source = FrigateSource(svc.factory, svc.tracking, mapping, clock=svc.clock)
    t0 = svc.clock.t
    frig_cams = {name: svc.cams[cid] for cid, name in names.items()}
    messages = frigate_messages(
        frig_cams, 0.5, _walkers(seed), minutes * 60.0, t0, np.random.default_rng(seed + 1)
    )
    print(f"  {len(messages)} Frigate events for {len(frig_cams)} cameras", flush=True)

    def extra() -> dict[str, float]:
        st = source.status()
        return {"held": st["held"], "inbox": st["inbox"], "late": st["late"]}

    svc.extra = extra
    delay, tick = 0.1, 0.05  # Frigate's processing and MQTT delay; the source's loop tick (s)
    i, k = 0, 0
    while svc.clock.t < t0 + minutes * 60.0:
        svc.clock.t = t0 + k * tick
        while i < len(messages) and messages[i][0] + delay <= svc.clock.t:
            source.handle(Message("frigate/events", messages[i][1].encode()))
            i += 1
        source.hold()
        svc.tracking.process(svc.clock.t + 0.01)
        if k % int(60 / tick) == 0:
            svc.sample(k * tick / 60.0)
        k += 1
    print(f"  Frigate source: {source.status()}")
    svc.report("Frigate soak", minutes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=120.0, help="real time of the twin run")
    parser.add_argument("--soak-minutes", type=float, default=30.0)
    parser.add_argument("--soak-rate", type=float, default=2.0, help="frames/s of each camera")
    parser.add_argument("--heap-top", type=int, default=0, help="print the top heap growths")
    parser.add_argument("--skip-twin", action="store_true")
    parser.add_argument("--light-seconds", type=float, default=90.0)
    parser.add_argument("--skip-light", action="store_true")
    parser.add_argument("--skip-soak", action="store_true")
    parser.add_argument("--skip-frigate-soak", action="store_true")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="bench-mqtt-broker-"))
    broker = Broker(folder)
    broker.start()
    try:
        if not args.skip_light:
            run_light(broker, args.light_seconds)
        if not args.skip_twin:
            run_twin(broker, args.seconds)
        if not args.skip_soak:
            run_soak(broker, args.soak_minutes, rate_hz=args.soak_rate, top=args.heap_top)
        if not args.skip_frigate_soak:
            run_frigate_soak(broker, args.soak_minutes, top=args.heap_top)
    finally:
        broker.kill()
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    threading.excepthook = lambda a: print("thread failed:", a.exc_value)
    main()
