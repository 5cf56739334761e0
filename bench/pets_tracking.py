"""Tracking the PETS clip through the service: the camera registered and placed in a running
`intspace serve`, the clip played by `intspace node` (or every frame's boxes posted at 7 Hz),
the stored tracks read back and scored with motmetrics on the floor (Euclidean, 1 m) against
the ground truth's world_x, world_y."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from scipy.optimize import linear_sum_assignment

from bench.pets_clip import (
    REPO,
    SIZE,
    SOURCE_FPS,
    Array,
    Truth,
    clip_video,
    load_truth,
    read_frames,
    video_path,
)
from bench.pets_placement import Placement, place_camera
from tests.support.service import WITHOUT_TWIN, clean_env, running_service

MATCH_M = 1.0  # motmetrics' gate on the floor
CAMERA = "pets_view_001"
# Capture times are rounded to microseconds in the node's log and the database.
EPS_S = 1e-3


@dataclass(frozen=True)
class TrackingRun:
    """What the service tracked from the node's detections: each person target's points
    (t, x, y), the number of robot targets, the capture time of the file's frame 0 and the
    node's log."""

    points: dict[int, Array]
    robot_targets: int
    t0: float
    node_log: str


def track_through_service(
    video: Path,
    placement: Placement,
    workdir: Path,
    posted: list[Any] | None = None,
    node_args: tuple[str, ...] = (),
) -> TrackingRun:
    """Start `intspace serve`, register and place the camera, play `video` through
    `intspace node --source VIDEO --camera NAME --source-fps 7` with an ingest token, and
    return the service's tracks. With `posted` (each frame's PersonBoxes and their
    appearances, detected beforehand), post every frame's boxes one frame each 1/7 s
    instead, as the node posts them: the node's figures on a machine that would keep up with
    every frame."""
    admin = "pets-bench-admin-token"
    with running_service(
        workdir / "data", token=admin, env=WITHOUT_TWIN, log_path=workdir / "serve.log"
    ) as service:
        http = httpx.Client(base_url=service.api, headers=service.headers, timeout=10)
        try:
            return _track(http, service.api, video, placement, workdir, posted, node_args)
        finally:
            http.close()


def _track(
    http: httpx.Client,
    api: str,
    video: Path,
    placement: Placement,
    workdir: Path,
    posted: list[Any] | None,
    node_args: tuple[str, ...],
) -> TrackingRun:
    """Register and place the camera in the running service, play or post the clip, and
    return the service's tracks (track_through_service)."""
    space = http.post("/spaces", json={"name": "PETS 2009 campus"})
    assert space.status_code == 201, space.text
    camera = http.post(
        "/cameras",
        json={
            "name": CAMERA,
            "space_id": space.json()["id"],
            "width": SIZE[0],
            "height": SIZE[1],
            "K": placement.K.tolist(),
            "dist": [0.0] * 5,
            "T_world_camera": placement.T_world_camera.tolist(),
        },
    )
    assert camera.status_code == 201, camera.text
    camera_id = camera.json()["id"]
    token = http.post(
        "/tokens", json={"name": "pets node", "scopes": ["ingest"], "camera_ids": [camera_id]}
    )
    assert token.status_code == 201, token.text
    ingest = token.json()["token"]
    if posted is None:
        t0, text = _play_node(video, api, ingest, workdir, node_args)
    else:
        t0, text = _post_frames(posted, api, ingest, camera_id)
    # The tracker releases the posted frames after its reorder window (1 s) and writes
    # tracks twice a second: wait that long, then until the stored tracks stop growing.
    time.sleep(2.0)
    points = _stored_tracks(http)
    for _ in range(20):
        time.sleep(0.5)
        again = _stored_tracks(http)
        if sum(len(p) for p in again.values()) == sum(len(p) for p in points.values()):
            break
        points = again
    robots = http.get("/targets", params={"state": "all", "kind": "robot"}).json()["total"]
    return TrackingRun(points=points, robot_targets=int(robots), t0=t0, node_log=text)


def _play_node(
    video: Path, api: str, token: str, workdir: Path, node_args: tuple[str, ...] = ()
) -> tuple[float, str]:
    """Run `intspace node` on `video` (with `node_args`) to its end; return the capture time
    of the file's frame 0 (what the node said) and the node's log."""
    node_env = clean_env()
    node_env["INTSPACE_TOKEN"] = token
    node_log = workdir / "node.log"
    with node_log.open("w") as log:
        node = subprocess.run(
            [
                sys.executable,
                "-m",
                "server.cli",
                "node",
                "--source",
                str(video),
                "--camera",
                CAMERA,
                "--source-fps",
                f"{SOURCE_FPS:g}",
                "--api",
                api,
                *node_args,
            ],
            cwd=REPO,
            env=node_env,
            stdout=subprocess.DEVNULL,
            stderr=log,
            timeout=1800,
        )
    text = node_log.read_text()
    if node.returncode != 0:
        raise RuntimeError(f"intspace node exited {node.returncode}:\n{text}")
    found = re.search(r"frame (\d+) of the file captured at ([0-9.]+)", text)
    if found is None:
        raise RuntimeError(f"the node did not say when its file's frames were captured:{text}")
    return float(found.group(2)) - int(found.group(1)) / SOURCE_FPS, text


def _post_frames(posted: list[Any], api: str, token: str, camera_id: int) -> tuple[float, str]:
    """POST /observations each frame's boxes (the node's own box_observations) at its capture
    time, frame k at t0 + k / 7 s on the service's clock (this machine's); return t0 and a
    line like the node's."""
    from server.node.runner import box_observations

    t0 = time.time() + 1.0
    detections = empty = 0
    with httpx.Client(headers={"Authorization": f"Bearer {token}"}, timeout=30) as client:
        for k, (found, looks) in enumerate(posted):
            t = t0 + k / SOURCE_FPS
            time.sleep(max(0.0, t - time.time()))
            obs = box_observations(camera_id, t, found, looks)
            body: dict[str, Any] = {"observations": obs}
            if not obs:
                body = {"empty_frames": [{"camera_id": camera_id, "t": t}]}
            answer = client.post(f"{api}/observations", json=body)
            if answer.status_code != 200:
                raise RuntimeError(f"POST /observations: {answer.status_code} {answer.text}")
            detections += len(obs)
            empty += not obs
    return t0, f"posted {detections} detection(s) and {empty} empty frame(s)"


def _stored_tracks(http: httpx.Client) -> dict[int, Array]:
    """Return every person target's stored track points (t, x, y), oldest first."""
    targets, offset = [], 0
    while True:
        page = http.get(
            "/targets", params={"state": "all", "kind": "person", "limit": 100, "offset": offset}
        ).json()
        targets += page["items"]
        offset += len(page["items"])
        if offset >= page["total"] or not page["items"]:
            break
    out = {}
    for target in targets:
        points: list[list[float]] = []
        until = None
        while True:
            params: dict[str, float | int] = {"limit": 1000}
            if until is not None:
                params["until"] = until
            chunk = http.get(f"/targets/{target['id']}/track", params=params).json()["points"]
            points = [[p["t"], *p["xy"]] for p in chunk] + points
            if len(chunk) < 1000:
                break
            until = chunk[0]["t"]
        if points:
            out[int(target["id"])] = np.asarray(points, dtype=np.float64)
    return out


@dataclass(frozen=True)
class TrackScore:
    mota: float
    idf1: float
    switches: int
    false_positives: int
    misses: int
    matches: int
    frames: int


def score_tracking(
    run: TrackingRun, truth: Truth, frames: int, hold_s: float | None = None, first: int = 1
) -> TrackScore:
    """Return the MOT metrics of the run on ground-truth frames first..frames: at frame f (captured
    at t0 + (f - 1) / 7) each target answers with its latest track point at most `hold_s` old
    (default: the tracker's coast_after, 0.5 s: until then GET /targets shows the target as
    confirmed at that point, which is what a user sees); hypotheses within 1 m of a conf 0
    person are first matched to them (Hungarian) and dropped, neither a miss nor a false
    positive."""
    import motmetrics as mm

    from core.localization import TrackerConfig

    hold = TrackerConfig().coast_after if hold_s is None else hold_s
    acc = mm.MOTAccumulator(auto_id=True)
    series = {tid: pts for tid, pts in run.points.items()}
    for f in range(first, frames + 1):
        tau = run.t0 + (f - 1) / SOURCE_FPS
        hyp_ids, hyp_xy = [], []
        for tid, pts in series.items():
            # The target's latest position at the frame's time, unless it is coasting: what
            # GET /targets shows then (a frame that missed the target, or that the node skipped,
            # leaves its previous position).
            j = int(np.searchsorted(pts[:, 0], tau + EPS_S, side="right")) - 1
            if j >= 0 and tau - pts[j, 0] <= hold + EPS_S:
                hyp_ids.append(tid)
                hyp_xy.append(pts[j, 1:3])
        hyp = np.asarray(hyp_xy, dtype=np.float64).reshape(-1, 2)
        rows = truth.rows(f)
        counted = rows & (truth.conf == 1)
        ignored = truth.world[rows & (truth.conf == 0)]
        gt = truth.world[counted]
        keep = np.ones(len(hyp), dtype=bool)
        if len(ignored) and len(hyp):
            every = np.vstack([gt, ignored])
            d = np.linalg.norm(every[:, None] - hyp[None], axis=2)
            cost = np.where(d <= MATCH_M, d, 1e6)
            r, c = linear_sum_assignment(cost)
            on_ignored = c[(r >= len(gt)) & (cost[r, c] < 1e6)]
            keep[on_ignored] = False
        ids = [h for h, k in zip(hyp_ids, keep, strict=True) if k]
        dist = mm.distances.norm2squared_matrix(gt, hyp[keep], max_d2=MATCH_M**2)
        acc.update(truth.ident[counted].tolist(), ids, dist)
    mh = mm.metrics.create()
    names = ["mota", "idf1", "num_switches", "num_false_positives", "num_misses", "num_matches"]
    row = mh.compute(acc, metrics=names, name="run").loc["run"]
    return TrackScore(
        mota=float(row["mota"]),
        idf1=float(row["idf1"]),
        switches=int(row["num_switches"]),
        false_positives=int(row["num_false_positives"]),
        misses=int(row["num_misses"]),
        matches=int(row["num_matches"]),
        frames=frames,
    )


def run_tracking(
    frames: int, workdir: Path, every_frame: bool = False, flip: bool = False
) -> tuple[TrackScore, TrackingRun, Placement]:
    """Place the camera, play the first `frames` frames of the clip through serve + node (or,
    `every_frame`, post every frame's boxes detected beforehand; `flip`, the detector's tiles
    and their mirror images) and score the tracks on ground-truth frames 1..frames."""
    truth = load_truth()
    placement = place_camera(truth)
    clip = clip_video(video_path(), frames, workdir / "clip.mkv")
    posted = None
    if every_frame:
        from core.localization.appearance import box_appearance
        from core.localization.ssd_people import SsdConfig, SsdPeopleDetector

        config = SsdConfig(flip=flip)
        dnn = SsdPeopleDetector(config=config)
        posted = []
        for image in read_frames(clip, frames):
            found = dnn.detect_boxes(image)
            posted.append((found, box_appearance(image, found.boxes)))
    node_args = ("--flip",) if flip else ()
    run = track_through_service(clip, placement, workdir, posted, node_args)
    return score_tracking(run, truth, frames), run, placement
