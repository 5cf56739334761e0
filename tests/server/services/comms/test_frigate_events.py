"""Frigate's messages turned into detections, without a broker: the box scaled from Frigate's
detect resolution to the camera's and measured as the observations API measures a box (core's
box_foot, then foot_on_axis: the stored detection is the foot of the body's axis and its
covariance), labels and false positives filtered, unknown cameras counted, a
camera registered later picked up, and `frigate/stats` giving the camera's health."""

from __future__ import annotations

import json

import numpy as np
from sqlalchemy import select

from core.localization import NetworkCamera, locate_monocular
from core.localization.boxes import box_foot, foot_on_axis
from server.db.models import Camera, Detection, Space
from server.services.comms.frigate import FrigateSource
from server.services.comms.mqtt import Message
from server.services.targets import LiveTargets
from server.services.tracking import TrackingService
from server.settings import FrigateCamera
from tests.support.frigate_replay import body_box
from tests.support.sqlite_copy import copied_database

K = [[700.0, 0.0, 640.0], [0.0, 700.0, 360.0], [0.0, 0.0, 1.0]]


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def _event(kind, camera, box, t, **extra):
    after = {
        "id": "1700000000.1-abc",
        "camera": camera,
        "frame_time": t,
        "label": "person",
        "false_positive": False,
        "box": box,
        "stationary": False,
        **extra,
    }
    return Message(
        "frigate/events", json.dumps({"type": kind, "before": after, "after": after}).encode()
    )


def test_frigate_events_become_detections_of_the_mapped_camera(tmp_path, sqlite_template):
    factory = copied_database(sqlite_template, tmp_path)
    with factory() as session:
        space = Space(name="Flat")
        session.add(space)
        session.commit()
        sid = space.id
    clock = Clock(1_800_000_000.0)
    tracking = TrackingService(factory, LiveTargets(factory), latency=0.5, clock=clock)
    beats: list[tuple[int, float, float | None]] = []
    source = FrigateSource(
        factory,
        tracking,
        {"front": FrigateCamera(camera="Hall", detect=(640, 360))},
        labels="person, dog",
        heartbeat=lambda *a: beats.append(a),
        clock=clock,
    )
    t = clock.t - 0.1
    cam = NetworkCamera.looking_at(K, None, [0, 0, 2.8], [3, 2, 0], (1280, 720))
    # A person standing at (2.5, 1.5) as Frigate boxes them (detect pixels, half the camera's).
    box = [round(float(v)) for v in body_box(cam, np.array([2.5, 1.5]), 0.5)]
    # The camera is not registered yet: counted, nothing stored.
    source.handle(_event("new", "front", box, t))
    assert source.counts["unknown_camera"] == 1
    with factory() as session:
        session.add(
            Camera(
                space_id=sid,
                name="Hall",
                width=1280,
                height=720,
                K=K,
                T_world_camera=cam.T_world_camera.tolist(),
            )
        )
        session.commit()
    source._refs.clear()  # as after the cache's few seconds
    source.handle(_event("new", "front", box, t))
    source.handle(_event("update", "back", [1, 2, 3, 4], t))  # a camera not mapped
    source.handle(_event("update", "front", [1, 2, 30, 40], t, label="car"))
    source.handle(_event("update", "front", [1, 2, 30, 40], t, false_positive=True))
    with factory() as session:
        rows = session.scalars(select(Detection)).all()
    # The false positive ended the object; the first box is the one stored.
    assert len(rows) == 1 and source.counts["fed"] == 1 and source.held() == []
    scaled = 2.0 * np.array([box], dtype=np.float64)  # from 640x360 to 1280x720
    want = foot_on_axis(scaled, box_foot(scaled), cam)
    assert want.measured[0]
    d = rows[0]
    # The same fit (the camera goes through the database: equal to 1e-6 px, px^2).
    assert np.allclose([d.u, d.v], want.pixel[0], rtol=0, atol=1e-6)
    assert d.height == 0.0 and d.kind == "person"
    assert np.allclose([[d.cxx, d.cxy], [d.cxy, d.cyy]], want.cov[0], rtol=1e-6, atol=1e-6)
    assert d.t >= t and d.label is None  # Frigate's id never names a target
    # The stored foot is the body's axis where the person stands (the replay's cylinder, 0.25 m
    # wide; within 5 cm for a box rounded to whole detect pixels, two camera pixels), not the
    # bottom centre, which is the body's near edge, about a radius nearer the camera.
    on_floor = locate_monocular(cam, np.array([[d.u, d.v]]), 0.0).xy[0]
    edge = locate_monocular(cam, box_foot(scaled).pixel, 0.0).xy[0]
    assert np.linalg.norm(on_floor - [2.5, 1.5]) < 0.05, on_floor
    assert np.linalg.norm(edge - [2.5, 1.5]) > 0.15, edge
    # A box touching the detect frame's bottom edge is cut there: no floor position from it.
    source.handle(_event("new", "front", [box[0], box[1], box[2], 360], t + 0.2))
    with factory() as session:
        assert len(session.scalars(select(Detection)).all()) == 1

    stats = {"cameras": {"front": {"camera_fps": 5.1, "process_fps": 5.0}}, "service": {}}
    source.handle(Message("frigate/stats", json.dumps(stats).encode()))
    assert beats and beats[-1][1] == 5.1 and beats[-1][2] == clock.t

    # Paths: a point per update is a Frigate that publishes each step of an object's path (its
    # silence bounds where the person is); points added between two updates are not.
    def pts(n):
        return [[[0.3 + 0.06 * k, 0.6], t + k] for k in range(n)]

    source.handle(_event("new", "front", box, t + 0.3, id="p", path_data=pts(1)))
    source.handle(_event("update", "front", box, t + 0.4, id="p", path_data=pts(2)))
    assert source.paths_published
    source.handle(_event("update", "front", box, t + 0.5, id="p", path_data=pts(4)))
    assert not source.paths_published
