"""Spec 08's acceptance through the service: four unsynchronised cameras, three walkers, sent
unlabelled through POST /observations, tracked by the space's one tracker, read back from
GET /targets and the stored tracks, and scored with motmetrics.

The conditions are the scenario's (core.sim.scenarios.multi_target_tracking: 10 Hz per camera
with its own phase, 0.7 px noise, 5 % missed detections, clutter, walkers crossing and pausing,
points at 1.0 m); only the length is shorter than the scenario's ten minutes. The service's
clock is driven by the test, so the tracker sees the frames exactly as a live service would, in
order, without the test waiting in real time."""

from __future__ import annotations

import time
from collections import Counter

import numpy as np
import pytest

from core.sim.camera_frames import ASYNC_HEIGHT_M, ASYNC_NOISE_PX, async_camera_frames
from core.sim.crowd import walkers_at
from core.sim.network_cameras import calibrated_cameras, frame_alignment, seen_by_any, true_cameras
from core.sim.scenarios import multi_target_tracking as ts
from core.sim.tracking_score import (
    POINT_TOLERANCE_S,
    TrackLog,
    score_tracks,
    transformed,
    truth_instants,
)

MINUTES = 2.0
SEED = 17  # not a seed the tracker's settings were chosen on (those were 0 and 3)
BATCH_S = 0.5


class _Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def _register(client, admin, cameras) -> list[int]:
    ids = []
    for cam in cameras:
        body = {
            "name": cam.name,
            "width": cam.image_size[0],
            "height": cam.image_size[1],
            "K": cam.K.tolist(),
            "dist": cam.dist.tolist(),
            "T_world_camera": cam.T_world_camera.tolist(),
        }
        response = client.post("/api/v1/cameras", json=body, headers=admin)
        assert response.status_code == 201, response.text
        ids.append(response.json()["id"])
    return ids


def _stored_tracks(client, admin) -> TrackLog:
    """Return every target's stored track, paged back with `until`."""
    log = TrackLog()
    targets = []
    offset = 0
    while True:
        page = client.get(
            f"/api/v1/targets?state=all&limit=100&offset={offset}", headers=admin
        ).json()
        targets += page["items"]
        offset += len(page["items"])
        if offset >= page["total"] or not page["items"]:
            break
    for target in targets:
        points: list[list[float]] = []
        until = None
        while True:
            query = f"/api/v1/targets/{target['id']}/track?limit=1000"
            if until is not None:
                query += f"&until={until}"
            chunk = client.get(query, headers=admin).json()["points"]
            points = chunk + points
            if len(chunk) < 1000:
                break
            until = chunk[0]["t"]
        if not points:
            continue
        log.points[target["id"]] = [(p["t"], p["xy"][0], p["xy"][1]) for p in points]
        log.confirmed_at[target["id"]] = points[0]["t"]
        if target["state"] == "ended":
            log.ended_at[target["id"]] = points[-1]["t"] + POINT_TOLERANCE_S
    return log


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_unlabelled_detections_from_unsynchronised_cameras_become_tracks(client, admin):
    scene = ts.tracking_scene()
    # The service knows the cameras as their network calibration placed them; the twin's true
    # cameras only make the images' points and score.
    calibrated = calibrated_cameras(scene, SEED).first(ts.ASYNC_CAMERAS)
    truth = true_cameras(scene)
    ids = dict(zip(calibrated.index, _register(client, admin, calibrated.cameras), strict=True))
    rng = np.random.default_rng(SEED)
    duration = 60.0 * MINUTES
    frames = [f for f in async_camera_frames(scene, truth, duration, rng) if f.camera in ids]

    tracking = client.app.state.runtime.tracking
    t0 = float(np.ceil(time.time())) + 1.0  # the capture times: Unix seconds from now on
    clock = _Clock(t0 - 1.0)
    tracking._clock = clock
    live_counts = []
    sigma = ASYNC_NOISE_PX
    submitted = tracking.frames_processed
    start = 0
    for batch_end in np.arange(BATCH_S, duration + BATCH_S, BATCH_S):
        stop = start
        while stop < len(frames) and frames[stop].t < batch_end:
            stop += 1
        observations = [
            {
                "camera_id": ids[f.camera],
                "t": t0 + f.t,
                "pixel": px.tolist(),
                "sigma_px": sigma,
                "kind": "person",
                "height": ASYNC_HEIGHT_M,
            }
            for f in frames[start:stop]
            for px in f.pixels
        ]
        start = stop
        if observations:
            response = client.post(
                "/api/v1/observations", json={"observations": observations}, headers=admin
            )
            assert response.status_code == 200, response.text
            assert response.json()["late"] == 0
            submitted += response.json()["frames"]
        # The service's clock reaches the batch's end: the tracker takes the whole batch.
        clock.t = t0 + batch_end + tracking.latency - 1e-6
        deadline = time.monotonic() + 10
        waiting = sum(len(s.buffer) for s in tracking._spaces.values())
        while tracking.frames_processed < submitted - waiting:
            assert time.monotonic() < deadline, "the tracker did not keep up"
            time.sleep(0.005)
        live_counts.append(len(tracking.tracks(None)))
    client.app.state.runtime.targets.flush()
    log = _stored_tracks(client, admin)

    truth_t, truth_xy = truth_instants(scene, duration)
    visible = seen_by_any([truth[i] for i in ids], truth_xy, ASYNC_HEIGHT_M)
    truth_xy = np.where(visible[..., None], truth_xy, np.nan)
    shifted = TrackLog(
        points={k: [(t - t0, x, y) for t, x, y in v] for k, v in log.points.items()},
        confirmed_at={k: v - t0 for k, v in log.confirmed_at.items()},
        ended_at={k: v - t0 for k, v in log.ended_at.items()},
    )
    # Scored in the calibrated frame: the frame's own rigid error (the calibration's gauge,
    # measured against the twin for scoring only) is the calibration's, not the service's.
    T = frame_alignment(calibrated.cameras, [truth[i] for i in ids])
    shifted = transformed(shifted, T)
    score = score_tracks(truth_t, truth_xy, shifted, truth_at=lambda t: walkers_at(scene, t))
    walkers = len(scene.people)
    # Spec 08's bars, at the scenario's conditions.
    assert score.idf1 >= 0.95, score
    assert score.mota >= 0.95, score
    assert score.id_switches <= max(1, round(walkers * MINUTES / 10.0)), score
    # Spec 08: never more live targets than bodies.
    assert max(live_counts) <= walkers, Counter(live_counts)
    assert score.class_rmse_m <= 0.05, score
