"""The home hears the space (spec 09): the twin's rooms over MQTT against the twin's truth, the
capture-to-MQTT latency, and a long run faster than real time that must not pile anything up.

Run from the repository root (Debian's mosquitto is started on a free port):
    python -m bench.bench_mqtt [--seconds 120] [--soak-minutes 30]

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
the default home's five cameras (2 frames a second each by default: the tracker's arithmetic,
not the clock, sets the pace) seeing three walkers who come and go (each present 90 s of every
120 s), projected with 0.7 px noise (no rendering: the frames' detections). Every simulated
minute it records what could pile up: the MQTT queue and its drops, the targets followed by the
zones, the publisher's per-target rate entries, the live targets and the tracker's tracks, and
the Python heap (tracemalloc). Nothing may grow with time: the last ten minutes' maxima must
not exceed the first ten's by more than the noise of three walkers (printed).
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
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_ROOT))

from tests.server.mqtt_broker import Broker, subscribe  # noqa: E402

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
    # Pair each true event with the nearest published one of its room and type.
    offsets = []
    unmatched = 0
    for kind, zone, t in true_events:
        cands = [abs(te - t) for k, z, te in est_events if k == kind and z == zone]
        if cands and min(cands) < 3.0:
            offsets.append(min(cands))
        else:
            unmatched += 1
    extra = len([e for e in est_events if e[0] in ("enter", "leave")]) - len(offsets)
    lat = np.array(latency) if latency else np.array([np.nan])
    out = {
        "instants": len(stamps),
        "true enter/leave": len(true_events),
        "published enter/leave": len([e for e in est_events if e[0] in ("enter", "leave")]),
        "matched": len(offsets),
        "missed": unmatched,
        "extra": extra,
        "event time offset median s": float(np.median(offsets)) if offsets else float("nan"),
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
    from server.services.home import HomePublisher
    from server.services.mqtt import BrokerUrl, MqttLink
    from server.services.targets import LiveTargets
    from server.services.tracking import DetectionIn, TrackingService
    from server.services.twin import bootstrap_space, registry_cameras
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


def run_soak(
    broker: Broker, minutes: float, rate_hz: float = 5.0, seed: int = 0, top: int = 0
) -> None:
    """Feed `minutes` of simulated time through the service's parts as fast as they go."""
    from core.sim import default_scene
    from server.db.session import make_engine, make_session_factory
    from server.services.home import HomePublisher
    from server.services.mqtt import BrokerUrl, MqttLink
    from server.services.targets import LiveTargets
    from server.services.tracking import DetectionIn, TrackingService
    from server.services.twin import bootstrap_space, registry_cameras
    from server.services.zones import ZoneService

    folder = Path(tempfile.mkdtemp(prefix="bench-mqtt-soak-"))
    factory = make_session_factory(make_engine(_migrated_sqlite(folder)))
    scene = default_scene()
    with factory() as session:
        space_id, camera_ids = bootstrap_space(session, scene)
        cams, _ = registry_cameras(session, list(camera_ids.values()))
    clock = _Clock(time.time())
    live = LiveTargets(factory, track_retention_s=120.0, detection_retention_s=60.0)
    tracking = TrackingService(factory, live, latency=0.5, clock=clock)
    zones = ZoneService(factory, owns=tracking.owns)
    tracking.target_listeners.append(zones.on_targets)
    link = MqttLink(BrokerUrl.parse(broker.url), queue_limit=10_000)
    home = HomePublisher(link, factory=factory, target_hz=2.0)
    zones.sinks.append(home)
    home.start()
    zones.reload()
    sub, rec = subscribe(broker, ["intspace/#"])

    rng = np.random.default_rng(seed)
    centre = np.array([[2.2, 3.0], [6.2, 1.5], [6.2, 4.5]])
    amp = np.array([[1.5, 2.0], [1.2, 1.0], [1.2, 1.0]])
    omega = rng.uniform(0.15, 0.3, (3, 2))
    phase = rng.uniform(0, 2 * np.pi, (3, 2))
    t0 = clock.t
    dt = 1.0 / rate_hz
    steps = int(minutes * 60 * rate_hz)
    tracemalloc.start()
    rows = []
    wall0 = time.perf_counter()
    for k in range(steps):
        s = k * dt
        clock.t = t0 + s
        xy = centre + amp * np.sin(omega * s + phase)
        present = ((s + 40.0 * np.arange(3)) % 120.0) < 90.0
        P = np.column_stack([xy[present], np.full(int(present.sum()), 1.0)])
        detections, empty = [], []
        for cid, cam in cams.items():
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
                        clock.t,
                        (float(p[0]), float(p[1])),
                        ((0.49, 0.0), (0.0, 0.49)),
                        "person",
                        1.0,
                    )
                )
            if not len(px):
                empty.append((cid, clock.t))
        with factory() as session:
            tracking.ingest(session, detections, dict.fromkeys(cams, space_id), empty=empty)
        tracking.process(clock.t + 0.01)
        if k % int(60 * rate_hz) == 0:
            live.flush()
            live.apply_retention(clock.t)
            status = link.status()
            # The service's heap: this bench's own subscriber (it keeps every message it
            # received) is left out; the tracker's record of its frames' delays (bounded at
            # 20,000 frames) is shown on its own.
            snap = tracemalloc.take_snapshot().filter_traces(
                [tracemalloc.Filter(False, "*mqtt_broker.py"), tracemalloc.Filter(False, "*paho*")]
            )
            heap = sum(st.size for st in snap.statistics("filename")) / 2**20
            if len(rows) == 2:
                early = snap
            if top and len(rows) >= 2:
                last_snap = snap
            delays = sum(
                st.size
                for st in snap.filter_traces(
                    [tracemalloc.Filter(True, "*node/clock.py")]
                ).statistics("filename")
            )
            if len(rows) == 1:
                print("  " + "  ".join(f"{k:>12}" for k in rows[0]), flush=True)
            if rows:
                r = rows[-1]
                print("  " + "  ".join(f"{v:>12.1f}" for v in r.values()), flush=True)
            rows.append(
                {
                    "minute": s / 60.0,
                    "queued": status["queued"],
                    "dropped": status["dropped"],
                    "zone targets": zones.followed(),
                    "rate entries": home.rate_entries(),
                    "live targets": len(live),
                    "tracks": len(tracking.tracks(space_id)),
                    "heap MiB": heap,
                    "delays MiB": delays / 2**20,
                }
            )
    wall = time.perf_counter() - wall0
    if top and len(rows) > 2:
        print("  heap growth since minute 2, by line:")
        for stat in last_snap.compare_to(early, "lineno")[:top]:
            print(f"    {stat}")
    time.sleep(2.0)
    final = link.status()
    home.stop()
    sub.loop_stop()
    sub.disconnect()
    tracemalloc.stop()
    shutil.rmtree(folder, ignore_errors=True)
    print(
        f"Soak: {minutes:g} simulated minutes in {wall:.0f} s of wall time "
        f"({minutes * 60 / wall:.1f}x real time), {rate_hz:g} Hz x {len(cams)} cameras"
    )
    keys = list(rows[0])
    print("  " + "  ".join(f"{k:>12}" for k in keys))
    for r in rows:
        print(
            "  "
            + "  ".join(
                f"{r[k]:>12.1f}" if isinstance(r[k], float) else f"{r[k]:>12}" for k in keys
            )
        )
    first = rows[1 : 1 + max(1, len(rows) // 3)] or rows
    last = rows[-max(1, len(rows) // 3) :]
    for key in (
        "queued",
        "zone targets",
        "rate entries",
        "live targets",
        "tracks",
        "heap MiB",
        "delays MiB",
    ):
        a = max(r[key] for r in first)
        b = max(r[key] for r in last)
        print(f"  {key:<14} first third max {a:8.1f}   last third max {b:8.1f}")
    events = sum(1 for _, t, _, _ in rec.messages if t.endswith("/events"))
    print(
        f"  MQTT: published {final['published']}, dropped {final['dropped']}, received by the "
        f"subscriber {len(rec.messages)} ({events} events)"
    )


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
    finally:
        broker.kill()
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    threading.excepthook = lambda a: print("thread failed:", a.exc_value)
    main()
