"""Paths: planning on the space's floor plan, the projector's joint trajectory, the refusals
(4xx naming the field) and the follow task on the twin."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from shapely.geometry import LineString, Point, Polygon

from core.calibration.projector import mount_errors
from core.localization import NetworkCamera
from core.navigation import AdaptiveLaw, Limits
from core.projector import PanTiltProjector, project_path
from core.sim import Renderer, default_scene
from core.sim.floor_camera import calibrate_floor_camera
from core.sim.projector import nominal_projector, twin_projector
from core.sim.scenarios.projector_calibration import projector_calibration
from core.sim.spot_following import (
    CORNER_RADIUS,
    LOOKAHEAD,
    PLAN_MARGIN,
    SPOT_ACCELERATION,
    simulate_following,
    start_pose,
)
from server.db.models import PlannedPath
from server.services import path_following
from server.services.path_following import FOLLOW_LEASES, follow_view
from server.services.twin_home import bootstrap_space
from tests.support.scene_recorder import SceneRecorder
from tests.support.waiting import task_progress, wait_while_advancing

SCENE = default_scene()
# A start in the living room and a goal in the kitchen: the route goes through the door in the
# wall x = 4.5 (y 1.0..1.9), past the bookshelf.
START, GOAL = [1.0, 2.5], [5.2, 1.45]


def _add_projector(client, admin, space: int, name: str = "ceiling_projector") -> tuple[int, int]:
    """Register a projector of `space` at the twin's nominal mount (what the installer
    entered); return (space id, projector id)."""
    pose = SCENE.projector.pose
    body = {
        "name": name,
        "space_id": space,
        "width": 1,
        "height": 1,
        "position": list(pose.position),
        "quaternion_xyzw": list(pose.quaternion_xyzw),
    }
    response = client.post("/api/v1/projectors", json=body, headers=admin)
    assert response.status_code == 201, response.text
    return space, response.json()["id"]


def _register_home(client, admin) -> tuple[int, int]:
    """Register the twin's home as the twin does (space named after it, its rooms) and its
    projector at the nominal mount; return (space id, projector id)."""
    space = client.post("/api/v1/spaces", json={"name": SCENE.name}, headers=admin).json()["id"]
    for room in SCENE.rooms:
        body = {"space_id": space, "name": room.name, "polygon": [list(p) for p in room.polygon]}
        assert client.post("/api/v1/rooms", json=body, headers=admin).status_code == 201
    return _add_projector(client, admin, space)


def _obstacles() -> list[tuple[object, float]]:
    """Return the scene's solid wall spans and furniture footprints as shapely geometry, each
    with the half thickness its surface lies from the geometry (walls: their centre lines)."""
    out: list[tuple[object, float]] = []
    for wall in SCENE.walls:
        a, b = np.asarray(wall.start, float), np.asarray(wall.end, float)
        u = (b - a) / np.linalg.norm(b - a)
        solid = LineString([a, b])
        for door in wall.doors:
            opening = LineString([a + u * door.offset, a + u * (door.offset + door.width)])
            solid = solid.difference(opening.buffer(1e-9, cap_style="flat"))
        out.append((solid, wall.thickness / 2))
    for f in SCENE.furniture:
        c, s = math.cos(f.yaw), math.sin(f.yaw)
        hx, hy = f.size[0] / 2, f.size[1] / 2
        corners = [(sx * hx, sy * hy) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        box = [(f.centre[0] + c * x - s * y, f.centre[1] + s * x + c * y) for x, y in corners]
        out.append((Polygon(box), 0.0))
    return out


def test_plan_in_the_twin_home_with_the_projector_trajectory(client, admin):
    space, projector = _register_home(client, admin)
    scene = SceneRecorder()
    client.app.state.runtime.scene_sync.scene = scene
    body = {"space_id": space, "start": START, "goal": GOAL, "projector_id": projector}
    response = client.post("/api/v1/paths", json=body, headers=admin)
    assert response.status_code == 201, response.text
    path = response.json()
    assert path["floor_plan"] == f"twin scene {SCENE.name!r}"
    # The live 3D scene draws the path and the projector at its mount, its beam on the first
    # spot the trajectory draws.
    assert scene.calls["set_planned_path"] == [(path["points"],)]
    (shown,) = scene.calls["set_projector"][0]
    assert shown.name == "ceiling_projector"
    assert shown.T_world_projector == path["projector_model"]["T_world_base"]
    assert shown.spot == path["trajectory"]["spot"][0]
    points = np.asarray(path["points"])
    assert np.allclose(points[0], START) and np.allclose(points[-1], GOAL)
    # The robot's radius (the scene's robot, 0.2 m) plus the 5 cm planning margin: every
    # segment keeps that far from every wall surface and furniture footprint, checked by
    # shapely on the scene's own geometry (independent of the planner's grid).
    clearance = SCENE.robot.base_radius + PLAN_MARGIN
    assert path["robot_radius_m"] == SCENE.robot.base_radius
    line = LineString(points)
    for geometry, half in _obstacles():
        assert line.distance(geometry) - half >= clearance - 1e-9
    # The straight line passes 0.27 m from the door's upper jamb (4.5, 1.9), inside the 0.30 m
    # the wall's half thickness and the clearance ask, so the route bends; the straight line is
    # a lower bound on the shortest route, and any-angle planning keeps within 2 % of it (the
    # issue's planning bound).
    straight = float(np.linalg.norm(np.subtract(GOAL, START)))
    assert len(points) >= 3 and path["length_m"] > straight
    assert path["length_m"] == pytest.approx(
        np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1))
    )
    assert path["length_m"] <= 1.02 * straight

    traj = path["trajectory"]
    t, q, spot = np.asarray(traj["t"]), np.asarray(traj["q"]), np.asarray(traj["spot"])
    assert np.all(np.diff(t) > 0) and t[-1] == pytest.approx(traj["duration_s"])
    # The forward map of the registered model (T_world_base = the registered pose) takes the
    # joint angles to the spots the trajectory says, to 10 um: core.projector interpolates the
    # angles and the spot linearly between path samples 5 mm apart (a second-order mismatch of
    # a few um on the bends) and the stored values are rounded to 1 um and 1e-8 rad.
    T = np.asarray(
        client.get(f"/api/v1/projectors/{projector}", headers=admin).json()["T_world_projector"]
    )
    model = PanTiltProjector(T)
    assert np.max(np.linalg.norm(model.spot(q) - spot, axis=1)) < 1e-5
    # The spot starts and ends on the path's ends, and never strays from the path by more than
    # the corner fillets cut (0.5 m radius on the bends of this path: under 10 cm here).
    assert np.allclose(spot[0], START, atol=1e-6) and np.allclose(spot[-1], GOAL, atol=1e-6)
    assert max(line.distance(Point(p)) for p in spot) < 0.1
    # Joint rates within the projector's limit (3 rad/s), and the spot never above its speed.
    assert np.max(np.abs(np.diff(q, axis=0)) / np.diff(t)[:, None]) <= 3.0 + 1e-6
    speed = np.linalg.norm(np.diff(spot, axis=0), axis=1) / np.diff(t)
    assert speed.max() <= 0.3 + 1e-3
    # At 0.3 m/s the drawing takes at least length / speed.
    assert traj["duration_s"] >= path["length_m"] / 0.3

    drawing = client.get(f"/api/v1/paths/floor-plan?space_id={space}", headers=admin).json()
    assert [r["name"] for r in drawing["rooms"]] == [r.name for r in SCENE.rooms]
    assert len(drawing["furniture"]) == len(SCENE.furniture)
    # Solid wall spans: each wall once, plus one more span per door inside it (the west door
    # is 2.5 m in, the living-room wall has two doors, the kitchen-bedroom wall one).
    assert len(drawing["walls"]) == len(SCENE.walls) + sum(len(w.doors) for w in SCENE.walls)
    assert drawing["clearance_m"] == pytest.approx(clearance)

    again = client.get(f"/api/v1/paths/{path['id']}", headers=admin)
    assert again.status_code == 200 and again.json()["points"] == path["points"]
    assert again.json()["follow"]["status"] == "idle"
    listing = client.get(f"/api/v1/paths?space_id={space}&limit=1", headers=admin).json()
    assert listing["total"] == 1 and listing["items"][0]["id"] == path["id"]
    assert "trajectory" not in listing["items"][0]


def test_refusals_name_the_reason(client, admin):
    space, projector = _register_home(client, admin)

    def plan(**body):
        return client.post(
            "/api/v1/paths",
            json={"space_id": space, "start": START, "goal": GOAL, **body},
            headers=admin,
        )

    def refused(response, status, field, words):
        assert response.status_code == status, response.text
        problem = response.json()
        assert problem["errors"][0]["field"] == field
        assert words in problem["detail"], problem["detail"]

    refused(plan(goal=[9.0, 9.0]), 422, "goal", "outside the floor plan")
    refused(plan(goal=[1.6, 4.2]), 422, "goal", "obstacle")  # on the coffee table
    refused(plan(start=[4.5, 0.5]), 422, "start", "wall")  # in the wall between the rooms
    refused(plan(space_id=999), 422, "space_id", "no space")
    refused(plan(projector_id=999), 422, "projector_id", "no projector")
    # Not even the request's shape: a third coordinate, a NaN.
    assert plan(goal=[1.0, 2.0, 3.0]).status_code == 422
    assert (
        client.post(
            "/api/v1/paths",
            content=b'{"space_id": 1, "start": [1, 1], "goal": [NaN, 1]}',
            headers={**admin, "Content-Type": "application/json"},
        ).status_code
        == 422
    )

    # A projector without a pose is uncalibrated.
    bare = {"name": "spare", "space_id": space, "width": 1, "height": 1}
    spare = client.post("/api/v1/projectors", json=bare, headers=admin).json()["id"]
    refused(plan(projector_id=spare), 409, "projector_id", "uncalibrated")
    # A projector of another space.
    other = client.post("/api/v1/spaces", json={"name": "elsewhere"}, headers=admin).json()["id"]
    away = {**bare, "name": "away", "space_id": other, "T_world_projector": np.eye(4).tolist()}
    away_id = client.post("/api/v1/projectors", json=away, headers=admin).json()["id"]
    refused(plan(projector_id=away_id), 422, "projector_id", "not in space")
    # A unit hung 0.3 m above the floor over the living room reaches 0.3 tan(1.35 rad) = 1.3 m
    # from its foot: it cannot draw a path into the kitchen.
    low = np.diag([1.0, -1.0, -1.0, 1.0])
    low[:3, 3] = [2.25, 3.0, 0.3]
    body = {**bare, "name": "low", "T_world_projector": low.tolist()}
    low_id = client.post("/api/v1/projectors", json=body, headers=admin).json()["id"]
    refused(plan(projector_id=low_id), 422, "projector_id", "cannot draw")
    # The twin's unit turns its pan from -180 to +180 deg: a path crossing the stop (the line
    # y = 3 west of the unit's foot at (2.25, 3)) cannot be drawn in one sweep.
    crossing = plan(start=[1.0, 2.5], goal=[1.0, 3.5], projector_id=projector)
    refused(crossing, 422, "projector_id", "pan past its limits")

    # No route: two rooms 1 m apart (a space with rooms only, no walls or furniture).
    apart = client.post("/api/v1/spaces", json={"name": "apart"}, headers=admin).json()["id"]
    for name, x0 in (("west", 0.0), ("east", 3.0)):
        polygon = [[x0, 0.0], [x0 + 2, 0.0], [x0 + 2, 2.0], [x0, 2.0]]
        room = {"space_id": apart, "name": name, "polygon": polygon}
        assert client.post("/api/v1/rooms", json=room, headers=admin).status_code == 201
    response = client.post(
        "/api/v1/paths",
        json={"space_id": apart, "start": [1.0, 1.0], "goal": [4.0, 1.0]},
        headers=admin,
    )
    refused(response, 422, "goal", "no collision-free route")
    response = client.post(
        "/api/v1/paths",
        json={"space_id": apart, "start": [0.5, 0.5], "goal": [1.5, 1.5]},
        headers=admin,
    )
    assert response.status_code == 201
    assert response.json()["floor_plan"].startswith("registered rooms")
    # Rooms only: the straight line is free.
    assert response.json()["points"] == [[0.5, 0.5], [1.5, 1.5]]
    # A path without a projector has nothing to follow; nor does one outside the twin's home.
    lone = response.json()["id"]
    response = client.post(f"/api/v1/paths/{lone}/follow", json={}, headers=admin)
    refused(response, 409, "path_id", "no projector trajectory")
    assert client.get("/api/v1/paths/999", headers=admin).status_code == 404
    assert client.post("/api/v1/paths/999/follow", json={}, headers=admin).status_code == 404
    response = client.post(f"/api/v1/paths/{lone}/follow", json={"law": "pid"}, headers=admin)
    assert response.status_code == 422


def _follow(client, admin, path_id: int, law: str, live: list | None = None) -> dict:
    """Start the follow task and poll it to its end; the polled states of the running task go
    to `live` when given."""
    response = client.post(
        f"/api/v1/paths/{path_id}/follow", json={"law": law, "seed": 3}, headers=admin
    )
    assert response.status_code == 202, response.text
    assert response.json()["follow"]["status"] == "running"
    # A second start while it runs is refused (the run takes over a second of CPU; this
    # request follows within milliseconds).
    again = client.post(f"/api/v1/paths/{path_id}/follow", json={"law": law}, headers=admin)
    assert again.status_code == 409 and "already" in again.json()["detail"]

    def read() -> dict:
        follow = client.get(f"/api/v1/paths/{path_id}", headers=admin).json()["follow"]
        if live is not None and follow["status"] == "running":
            live.append(follow)
        return follow

    # Waits while the follow advances (a busy machine slows it, it does not stop it); its
    # set-up (the twin's renderer) reports no progress for a while before the first step.
    return wait_while_advancing(
        read,
        done=lambda follow: follow["status"] != "running",
        progress=task_progress,
        stalled_after_s=120.0,
        poll_s=0.05,
        what="the follow task",
    )


def test_follow_on_the_twin(client, admin, monkeypatch):
    # The series so far is written every 0.5 s of wall time; every 50 ms here, so that the
    # polls below see the run's partial series however fast the machine runs it.
    monkeypatch.setattr(path_following, "_HEARTBEAT_S", 0.05)
    space, projector = _register_home(client, admin)
    # A straight 2.7 m across the living room (a short run keeps the test quick).
    body = {"space_id": space, "start": START, "goal": [3.5, 1.6], "projector_id": projector}
    path = client.post("/api/v1/paths", json=body, headers=admin).json()
    assert len(path["points"]) == 2
    live: list[dict] = []
    adaptive = _follow(client, admin, path["id"], "adaptive", live)
    assert adaptive["status"] == "succeeded", adaptive["error"]
    assert adaptive["law"] == "adaptive" and adaptive["seed"] == 3 and adaptive["progress"] == 1
    result = adaptive["result"]
    # The service runs the core's closed loop: the same run straight from core (same seed, same
    # trajectory) gives the same errors.
    scene = SCENE
    model = nominal_projector(scene).with_pose(
        client.get(f"/api/v1/projectors/{projector}", headers=admin).json()["T_world_projector"]
    )
    traj = project_path(
        model,
        np.asarray(path["points"]),
        0.3,
        spot_acceleration=SPOT_ACCELERATION,
        corner_radius=CORNER_RADIUS,
    )
    law = AdaptiveLaw(
        LOOKAHEAD, Limits(scene.robot.limits.max_speed, scene.robot.limits.max_turn_rate)
    )
    # Both render every floor-camera frame (a renderer of their own: the same images).
    renderer = Renderer(scene, supersample=1)
    plane = calibrate_floor_camera(np.random.default_rng([3, 7]), renderer)
    run = simulate_following(
        law,
        traj,
        twin_projector(scene, 3),
        plane,
        start_pose(traj),
        scene,
        3,
        renderer=renderer,
    )
    assert result["rms_m"] == pytest.approx(run.rms, abs=1e-12)
    series = adaptive["series"]
    assert len(series["t"]) == len(series["error_m"]) == len(run.time[::10])
    assert np.allclose(series["error_m"], run.error[::10], atol=1e-5)  # stored to 10 um
    # The robot's pose and the spot, stored to 0.1 mm (and 0.1 mrad).
    pose = np.column_stack([series["x"], series["y"], series["theta"]])
    assert np.allclose(pose, run.pose[::10], atol=1e-4)
    assert np.allclose(
        np.column_stack([series["spot_x"], series["spot_y"]]), run.spot[::10], atol=1e-4
    )
    # While it ran, GET showed the series so far: each a prefix of the final one, growing, with
    # the progress of its last sample's time.
    partial = [f for f in live if f["series"] is not None]
    assert partial, "no poll saw the running task's series"
    lengths = [len(f["series"]["t"]) for f in partial]
    assert lengths == sorted(lengths) and lengths[0] < len(series["t"])
    for f in partial:
        n = len(f["series"]["t"])
        assert all(len(v) == n for v in f["series"].values())
        assert all(v == series[k][:n] for k, v in f["series"].items())
        # The progress is the simulated time at the write over the drawing's duration; the
        # last kept sample is at most one series step (0.2 s) older.
        duration = path["trajectory"]["duration_s"]
        lag = f["progress"] - min(1.0, f["series"]["t"][-1] / duration)
        assert -1e-9 <= lag <= 0.2 / duration + 1e-3


def test_a_task_whose_heartbeat_stopped_reads_as_interrupted():
    # A follow task's service renews its 30 s lease every 5 s while it runs; one not renewed
    # for longer than 30 s belonged to a service that stopped.
    beat = datetime(2026, 1, 1, tzinfo=UTC)
    row = PlannedPath(follow_status="running", **FOLLOW_LEASES.lease("s:1:0", beat))
    assert follow_view(row, now=beat + timedelta(seconds=29)).status == "running"
    assert follow_view(row, now=beat + timedelta(seconds=31)).status == "interrupted"
    row.follow_status = "succeeded"
    assert follow_view(row, now=beat + timedelta(hours=1)).status == "succeeded"


def test_projector_calibration_run_on_the_twin(client, admin, run_waiter):
    # The registry as the twin's first start leaves it: the home, its cameras with their
    # installed calibration, its robot; then the projector at the nominal mount entered.
    with client.app.state.runtime.session_factory() as session:
        space, _ = bootstrap_space(session, SCENE)
    _, projector = _add_projector(client, admin, space)
    body = {"kind": "projector", "projector_id": projector, "seed": 2, "images": False}
    response = client.post("/api/v1/calibration-runs", json=body, headers=admin)
    assert response.status_code == 202, response.text
    run = run_waiter(client, response.json()["id"])
    assert run["status"] == "succeeded", run["error"]
    result = run["result"]
    assert result["kind"] == "projector" and result["projector_id"] == projector

    # The run is the twin's projector-calibration scenario with the registry's cameras: the
    # same call straight from core gives the same mount.
    listed = client.get(f"/api/v1/cameras?space_id={space}", headers=admin).json()["items"]
    cameras = [
        NetworkCamera.from_pose(
            c["K"], c["dist"], c["T_world_camera"], (c["width"], c["height"]), c["name"]
        )
        for c in listed
    ]
    direct = projector_calibration(SCENE, 2, cameras=cameras, images=False)
    assert np.allclose(result["T_world_projector"], direct.model.T_world_base, atol=1e-9)
    assert result["spots"] == direct.spots >= 12
    # Against the twin's true mount (seed 2 puts it 5.2 cm and 2.19 deg off the nominal): the
    # calibration at least halves the rotation error. The spots are located with ~2 cm RMS
    # error (the installed camera calibration's, twice the 1 cm of the spec's bound), most of
    # it a common frame error of the cameras' own calibration; with that removed (aligned), the
    # mount is within 2 cm and 0.2 deg of the truth.
    truth = twin_projector(SCENE, 2)
    _, nominal_rotation = mount_errors(nominal_projector(SCENE).T_world_base, truth.T_world_base)
    errors = result["twin_errors"]
    assert errors["rotation_deg"] < nominal_rotation / 2
    assert errors["aligned_position_m"] < 0.02 and errors["aligned_rotation_deg"] < 0.2

    applied = client.post(f"/api/v1/calibration-runs/{run['id']}/apply", headers=admin)
    assert applied.status_code == 200, applied.text
    assert np.allclose(applied.json()["T_world_projector"], result["T_world_projector"])
    again = client.post(f"/api/v1/calibration-runs/{run['id']}/apply", headers=admin)
    assert again.status_code == 200
    history = client.get(f"/api/v1/projectors/{projector}/calibrations", headers=admin).json()
    assert history["total"] == 1  # applying the run in force again adds nothing
    assert history["items"][0]["calibration_run_id"] == run["id"]
    assert history["items"][0]["tilt_offset"] == pytest.approx(result["tilt_offset_rad"])
    # Paths are now drawn with the calibrated mount and its tilt offset.
    plan = {"space_id": space, "start": START, "goal": GOAL, "projector_id": projector}
    path = client.post("/api/v1/paths", json=plan, headers=admin)
    assert path.status_code == 201, path.text
    row_model = path.json()["projector_model"]
    assert row_model["theta"][1] == pytest.approx(result["tilt_offset_rad"])
    assert np.allclose(row_model["T_world_base"], result["T_world_projector"])

    # Refusals: one camera cannot locate a spot on the floor; a projector of another space.
    one = {**body, "camera_ids": [listed[0]["id"]]}
    response = client.post("/api/v1/calibration-runs", json=one, headers=admin)
    assert response.status_code == 422 and "two calibrated cameras" in response.json()["detail"]
    other = client.post("/api/v1/spaces", json={"name": "elsewhere"}, headers=admin).json()["id"]
    _, away = _add_projector(client, admin, other, name="away")
    response = client.post(
        "/api/v1/calibration-runs", json={**body, "projector_id": away}, headers=admin
    )
    assert response.status_code == 409 and "twin's home" in response.json()["detail"]
