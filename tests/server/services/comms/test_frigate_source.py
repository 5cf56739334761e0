"""Frigate as a source, against a real broker: a replay of Frigate's events (its real message
pattern: new, sparse updates, nothing while a person stands still, end) for two cameras that see
the same three walkers. The occupancy the service publishes never counts a person twice, the
live people never outnumber the walkers present, a person standing still for 12 s (longer than
the tracker's 5 s end and Frigate's 5 s between snapshots) stays counted, and the tracking is
scored (CLEAR MOT and IDF1 against the walkers' paths, the replay's truth, for scoring only)
beside the tracker's own figures on the same walkers: every box the two cameras' detector saw,
posted at its steady frame rate to the observations API of a second space in the same service
at the same time."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import motmetrics as mm
import numpy as np
import paho.mqtt.client as paho
import pytest
from fastapi.testclient import TestClient

from core.geometry.polygon import points_in_polygons
from core.localization import NetworkCamera
from server.app import create_app
from tests.support.frigate_replay import DETECT_FPS, Publisher, frigate_messages
from tests.support.mqtt_broker import PASSWORD, USER, broker, subscribe  # noqa: F401

K = [[700.0, 0.0, 640.0], [0.0, 700.0, 360.0], [0.0, 0.0, 1.0]]
ROOM = [[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]]
# The replay ends as B, the last walker, stops (at 22 s).
DURATION = 22.6
STILL = (4.0, 16.0)  # walker A stands at (3, 2) for 12 s


def _lerp(t, t0, t1, a, b):
    s = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
    return np.asarray(a) + s * (np.asarray(b) - np.asarray(a))


def positions(t: float) -> np.ndarray:
    """The walkers' true floor positions (3, 2) at replay time t; NaN where absent."""
    nan = [np.nan, np.nan]
    if t < 4:
        a = _lerp(t, 0, 4, (0.8, 1.0), (3.0, 2.0))
    elif t < 16:
        a = np.array([3.0, 2.0])
    else:
        a = _lerp(t, 16, 20, (3.0, 2.0), (5.0, 3.0))
    if t < 2:
        b = nan
    elif t < 12:
        b = _lerp(t, 2, 12, (5.5, 0.8), (1.0, 3.2))
    else:
        b = _lerp(t, 12, 22, (1.0, 3.2), (5.0, 1.0))
    if t < 6 or t >= 16:
        c = nan
    elif t < 12:
        c = _lerp(t, 6, 12, (0.5, 3.5), (2.5, 0.8))
    else:
        c = _lerp(t, 12, 16, (2.5, 0.8), (-2.5, 0.8))
    return np.array([a, b, c], dtype=np.float64)


# The detect resolution is half the cameras' (Frigate's boxes are scaled by 2 on the way in).
SCALE = 0.5
DETECT = (640, 360)
# Metres: a live person further than this from a walker is not that walker (CLEAR MOT's gate).
MATCH_M = 1.0


def _cameras() -> dict[str, NetworkCamera]:
    return {
        "front": NetworkCamera.looking_at(K, None, [-0.3, -0.3, 2.8], [3.0, 2.0, 0.0], (1280, 720)),
        "back": NetworkCamera.looking_at(K, None, [6.3, 4.3, 2.8], [3.0, 2.0, 0.0], (1280, 720)),
    }


def _register(client, admin, space: str, names: dict[str, str]) -> tuple[int, dict[str, int]]:
    """Create a space with the room and the two cameras; return its id and the camera ids."""
    sid = client.post("/api/v1/spaces", json={"name": space}, headers=admin).json()["id"]
    room = {"space_id": sid, "name": "Living", "polygon": ROOM}
    assert client.post("/api/v1/rooms", json=room, headers=admin).status_code == 201
    ids = {}
    for f, cam in _cameras().items():
        body = {
            "name": names[f],
            "space_id": sid,
            "width": 1280,
            "height": 720,
            "K": K,
            "T_world_camera": cam.T_world_camera.tolist(),
        }
        answer = client.post("/api/v1/cameras", json=body, headers=admin)
        assert answer.status_code == 201
        ids[f] = answer.json()["id"]
    return sid, ids


class SteadyPoster(threading.Thread):
    """Posts every detect frame of the replay (its boxes, or an empty frame) to /observations
    once the wall clock reaches its capture time plus `delay`, as a camera node detecting at
    DETECT_FPS would; frames that fell due while a post was on its way go in the next one, as
    a node's buffer sends them."""

    def __init__(self, client, admin, frames, cameras: dict[str, int], delay: float) -> None:
        super().__init__(daemon=True)
        self.client, self.admin = client, admin
        self.frames = sorted(frames, key=lambda f: f[0])
        self.cameras, self.delay = cameras, delay
        self.failed: list[int] = []
        self.lag: list[float] = []  # how long after it fell due each frame was answered (s)

    def run(self) -> None:
        k = 0
        while k < len(self.frames):
            wait = self.frames[k][0] + self.delay - time.time()
            if wait > 0:
                time.sleep(wait)  # time must pass: a node posts a frame once it falls due
            now = time.time()
            due = []
            while k < len(self.frames) and self.frames[k][0] + self.delay <= now:
                due.append(self.frames[k])
                k += 1
            body: dict[str, Any] = {"observations": [], "empty_frames": []}
            for frame_time, name, boxes in due:
                self._add(body, frame_time, self.cameras[name], boxes)
            answer = self.client.post("/api/v1/observations", json=body, headers=self.admin)
            if answer.status_code != 200:
                self.failed.append(answer.status_code)
            done = time.time()
            self.lag.extend(done - (frame_time + self.delay) for frame_time, _, _ in due)

    @staticmethod
    def _add(body: dict[str, Any], frame_time: float, cid: int, boxes) -> None:
        w, h = DETECT
        if not boxes:
            body["empty_frames"].append({"camera_id": cid, "t": frame_time})
        for box in boxes:
            b = np.round(box)  # Frigate's boxes are whole detect pixels
            cut = [
                side
                for side, edge in (
                    ("bottom", b[3] >= h - 1),
                    ("top", b[1] <= 1),
                    ("left", b[0] <= 1),
                    ("right", b[2] >= w - 1),
                )
                if edge
            ]
            body["observations"].append(
                {
                    "camera_id": cid,
                    "t": frame_time,
                    "box": (b / SCALE).tolist(),
                    "kind": "person",
                    **({"cut": cut} if cut else {}),
                }
            )


def _score(samples, space_id: int, t0: float) -> tuple[dict[str, float], list[str]]:
    """Return the CLEAR MOT / IDF1 figures of a space's live people over the samples, each
    compared with the walkers at the tracker's time (the capture time up to which it has taken
    its frames: its reorder latency, and more under load), and walker A's event types during
    the still period after its first 2 s."""
    still_events: list[str] = []
    acc = mm.MOTAccumulator(auto_id=True)
    for _, t_track, items in samples:
        people = [v for v in items if v["kind"] == "person" and v["space_id"] == space_id]
        t_replay = t_track[space_id] - t0
        truth_now = positions(t_replay)
        present = [w for w in range(3) if not np.isnan(truth_now[w, 0])]
        hyp = np.array([v["xy"] for v in people]).reshape(-1, 2)
        dist = mm.distances.norm2squared_matrix(truth_now[present], hyp, max_d2=MATCH_M**2)
        # Hypothesis ids: the track number of the label ("person-<space>-<track>").
        hyp_ids = [int(v["label"].rsplit("-", 1)[1]) for v in people]
        frame = acc.update(present, hyp_ids, dist)
        if STILL[0] + 2.0 <= t_replay <= STILL[1]:
            events = acc.mot_events.loc[frame]
            still_events.extend(events[events["OId"] == 0]["Type"].tolist())
    summary = mm.metrics.create().compute(
        acc,
        metrics=[
            "num_switches",
            "idf1",
            "mota",
            "num_false_positives",
            "num_misses",
            "num_objects",
        ],
    )
    return {k: float(summary[k].iloc[0]) for k in summary.columns}, still_events


# Real time (28 s): run on SQLite only; the ingest it shares with the API runs on both.
@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_frigate_replay_two_cameras_three_walkers(broker, make_settings, admin):  # noqa: F811
    cams = _cameras()
    names = {"front": "Hall cam", "back": "Window cam"}
    settings = make_settings(
        mqtt_url=broker.url,
        frigate_mqtt=broker.url,
        frigate_cameras={f: {"camera": names[f], "detect": list(DETECT)} for f in cams},
        tracker_latency_s=0.5,
    )
    sub, rec = subscribe(broker, ["intspace/#"])
    with TestClient(create_app(settings)) as client:
        # Registered after the service started: picked up when Frigate's events arrive.
        sid, _ = _register(client, admin, "Flat", names)
        # The reference: the same cameras in a second space, fed every frame's boxes.
        ref_sid, ref_ids = _register(
            client, admin, "Lab", {f: f"{n} (steady)" for f, n in names.items()}
        )
        live = client.app.state.runtime.targets
        tracking = client.app.state.runtime.tracking

        t0 = time.time() + 0.5
        rng = np.random.default_rng(4)
        frames: list[tuple[float, str, list[np.ndarray]]] = []
        messages = frigate_messages(cams, SCALE, positions, DURATION, t0, rng, frames=frames)
        # Frigate's clutter and other labels are not people: they must change nothing.
        noise = json.loads(messages[0][1])
        for kind, extra in (("new", {"label": "car"}), ("new", {"false_positive": True})):
            after = {**noise["after"], "id": f"x{kind}{len(extra)}", **extra}
            messages.append((t0 + 1.0, json.dumps({"type": kind, "before": after, "after": after})))
        messages.sort(key=lambda m: m[0])
        counts = {
            k: sum(json.loads(p)["type"] == k for _, p in messages)
            for k in ("new", "update", "end")
        }

        pub = paho.Client(paho.CallbackAPIVersion.VERSION2)
        pub.username_pw_set(USER, PASSWORD)
        pub.connect("127.0.0.1", broker.port)
        pub.loop_start()
        replay = Publisher(pub, messages, delay=0.1)
        # A node posts a frame once it has detected it: the same 0.1 s as Frigate's delay.
        steady = SteadyPoster(client, admin, frames, ref_ids, delay=0.1)
        samples: list[tuple[float, dict[int, float], list[dict]]] = []
        stop = threading.Event()

        def sample() -> None:
            while not stop.is_set():
                _, items = live.snapshot()
                now = time.time()
                t_track = {}
                for s in (sid, ref_sid):
                    released = tracking.released(s)
                    t_track[s] = now - 0.5 if released is None else released
                live_items = [v for v in items if v["state"] in ("confirmed", "coasting")]
                samples.append((now, t_track, live_items))
                stop.wait(0.25)

        sampler = threading.Thread(target=sample, daemon=True)
        replay.start()
        steady.start()
        sampler.start()
        replay.join(DURATION + 10)
        steady.join(10)
        # Time must pass: the sampler goes on watching through the tracker's latency and the
        # zones' inertia after the last frame, when a double count would show.
        time.sleep(2.0)
        stop.set()
        sampler.join(2)
        status = client.get("/api/v1/home/status", headers=admin).json()
        pub.loop_stop()
        pub.disconnect()
    sub.loop_stop()
    sub.disconnect()

    frigate = status["frigate"]
    assert frigate["unknown_camera"] == 0 and frigate["errors"] == 0 and frigate["dropped"] == 0
    assert frigate["fed"] == counts["new"] + counts["update"] - 2  # the car and the clutter
    assert len(frames) == round(2 * DURATION * DETECT_FPS)
    topic = "intspace/flat/zones/living/occupancy"
    occupancy = [(t, int(p)) for t, tp, p, _ in rec.messages if tp == topic and p]
    ref_topic = "intspace/lab/zones/living/occupancy"
    ref_occupancy = [(t, int(p)) for t, tp, p, _ in rec.messages if tp == ref_topic and p]

    def true_inside(tw: float) -> int:
        xy = positions(tw - t0)
        ok = ~np.isnan(xy[:, 0])
        return int(points_in_polygons(xy[ok], [ROOM])[:, 0].sum()) if ok.any() else 0

    def true_present(tw: float) -> int:
        return int((~np.isnan(positions(tw - t0)[:, 0])).sum())

    # Never counts a person twice: the published count never exceeds the people truly inside
    # over the last 3 s (the tracker's latency, Frigate's delay, the inertia and the `end`).
    def double_counts(published) -> list[tuple[float, int, int]]:
        out = []
        for tw, n in published:
            truth = max(true_inside(tw - d) for d in np.arange(0.0, 3.01, 0.1))
            if n > truth:
                out.append((tw - t0, n, truth))
        return out

    doubles, ref_doubles = double_counts(occupancy), double_counts(ref_occupancy)
    figures, still_events = _score(samples, sid, t0)
    reference, _ = _score(samples, ref_sid, t0)
    print(
        f"Frigate replay: {counts} messages, fed {frigate['fed']}, re-fed {frigate['refed']}, "
        f"late {frigate['late']}; Frigate {figures}, occupancy double counts {len(doubles)}; "
        f"steady {reference}, occupancy double counts {len(ref_doubles)}, "
        f"posted {np.percentile(steady.lag, 95):.2f} s after due (p95)"
    )
    assert not steady.failed, steady.failed
    # The reference is the tracker given every frame: when it does not follow the walkers (a
    # machine too busy to post the frames within the tracker's latency) there is nothing to
    # compare with. Spec 08 asks MOTA >= 0.95 of it on clean pixels; boxes cost some (0.91-0.94
    # in these runs).
    assert reference["mota"] >= 0.85, reference
    assert not doubles, doubles
    # A and B stand in the room at the end (Frigate keeps them, stationary); C left.
    assert occupancy[-1][1] == 2

    # Never more live people than walkers present (within the same 3 s).
    for tw, _, items in samples:
        people = [v for v in items if v["kind"] == "person" and v["space_id"] == sid]
        truth = max(true_present(tw - d) for d in np.arange(0.0, 3.01, 0.1))
        assert len(people) <= truth, (tw - t0, len(people), truth)
        # Frigate's ids are for display only: no target is named after one.
        assert all(v["label"].startswith("person-") for v in people)

    # The person standing still (Frigate says nothing for 5 s at a time) stays counted: matched
    # at every sample of the still period after its first 2 s, with no switch.
    assert still_events and set(still_events) == {"MATCH"}, still_events
    inside = [n for tw, n in occupancy if STILL[0] + 3.0 <= tw - t0 <= STILL[1]]
    assert min(inside, default=1) >= 1
    # The tracker's own figures on Frigate's sparse reports, against the same tracker given
    # every frame: no more identity switches, an IDF1 at most 0.05 below (Frigate's reports
    # lag a walker by up to a path step, about 0.4 m here), and a target more than 1 m from
    # every walker (a false positive) as rare as 5 % of the walkers' samples.
    assert figures["num_switches"] <= reference["num_switches"], (figures, reference)
    assert figures["idf1"] >= reference["idf1"] - 0.05, (figures, reference)
    assert figures["num_false_positives"] <= 0.05 * figures["num_objects"], figures
