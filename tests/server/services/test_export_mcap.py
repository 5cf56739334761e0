"""`GET /spaces/{id}/export.mcap`: a time range of a space as MCAP with Foxglove's schemas,
read back with the mcap package's reader and checked against the stored rows."""

from __future__ import annotations

import io
import json
import math
import time

import numpy as np
import pytest
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from server.db.models import Detection, Target, TrackPoint
from server.services.export import check_range

K = [[330.0, 0.0, 321.5], [0.0, 330.0, 238.2], [0.0, 0.0, 1.0]]
DIST = [-0.28, 0.07, 0.0006, -0.0004, 0.0]
# Recent times: the service's retention deletes detections older than an hour.
T0 = float(int(time.time()) - 120)
# A ceiling camera 2.8 m up looking down (its z axis along world -z), turned 30 degrees.
R = Rotation.from_euler("xz", [180.0, 30.0], degrees=True).as_matrix()
POSE = np.vstack([np.hstack([R, [[0.3], [0.3], [2.8]]]), [0, 0, 0, 1]]).tolist()


def _space(client, admin, name: str) -> int:
    response = client.post("/api/v1/spaces", json={"name": name}, headers=admin)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _camera(client, admin, space_id: int, name: str, posed: bool) -> int:
    body = {"name": name, "width": 640, "height": 480, "space_id": space_id, "K": K, "dist": DIST}
    if posed:
        body["T_world_camera"] = POSE
    response = client.post("/api/v1/cameras", json=body, headers=admin)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _detection(space_id, camera_id, t, u, v, kind="robot", cov=(0.25, 0.0, 0.25)):
    return Detection(
        space_id=space_id,
        camera_id=camera_id,
        t=t,
        u=u,
        v=v,
        cxx=cov[0],
        cxy=cov[1],
        cyy=cov[2],
        kind=kind,
        height=0.36 if kind == "robot" else 1.0,
        label=None,
    )


def _read(content: bytes) -> tuple[dict, list]:
    reader = make_reader(io.BytesIO(content))
    messages = list(reader.iter_messages())
    return reader.get_summary(), messages


def test_export_writes_detections_tracks_poses_and_calibrations_of_the_range(client, admin):
    space = _space(client, admin, "home")
    other = _space(client, admin, "elsewhere")
    cam_a = _camera(client, admin, space, "cam_a", posed=True)
    cam_b = _camera(client, admin, space, "cam_b", posed=False)
    cam_c = _camera(client, admin, other, "cam_c", posed=True)
    factory = client.app.state.runtime.session_factory
    with factory() as session:
        session.add_all(
            [
                _detection(space, cam_a, T0, 10.0, 20.0),
                _detection(space, cam_a, T0, 30.0, 40.0, "person", (4.0, 1.0, 9.0)),
                _detection(space, cam_a, T0 + 0.1, 11.0, 21.0),
                _detection(space, cam_b, T0 + 0.05, 50.0, 60.0, "unknown"),
                _detection(space, cam_a, T0 - 50.0, 1.0, 1.0),  # before the range
                _detection(other, cam_c, T0, 5.0, 5.0),  # another space
            ]
        )
        robot = Target(space_id=space, label="robot", kind="robot", state="confirmed")
        person = Target(space_id=space, label="person-1", kind="person", state="confirmed")
        stranger = Target(space_id=other, label="person-9", kind="person", state="confirmed")
        session.add_all([robot, person, stranger])
        session.flush()
        cov = [[1e-4, 0.0], [0.0, 1e-4]]
        robot_points = [(T0 + 0.1 * k, 1.0 + 0.05 * k, 1.2) for k in range(5)]
        session.add_all(
            [TrackPoint(target_id=robot.id, t=t, x=x, y=y, cov=cov) for t, x, y in robot_points]
            + [
                TrackPoint(target_id=person.id, t=T0 + 0.02 + 0.2 * k, x=2.0, y=0.5 * k, cov=cov)
                for k in range(3)
            ]
            + [
                TrackPoint(target_id=robot.id, t=T0 + 100.0, x=9.0, y=9.0, cov=cov),  # after
                TrackPoint(target_id=stranger.id, t=T0, x=0.0, y=0.0, cov=cov),
            ]
        )
        session.commit()

    response = client.get(
        f"/api/v1/spaces/{space}/export.mcap",
        params={"since": T0 - 1.0, "until": T0 + 1.0},
        headers=admin,
    )
    assert response.status_code == 200, response.text
    assert "attachment" in response.headers["content-disposition"]
    summary, messages = _read(response.content)
    by_topic: dict[str, list] = {}
    for schema, channel, message in messages:
        assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
        assert schema.name.startswith("foxglove.")
        assert json.loads(schema.data)["title"] == schema.name
        by_topic.setdefault(channel.topic, []).append((schema.name, message))
    assert set(by_topic) == {
        "/cameras/cam_a/calibration",
        "/cameras/cam_b/calibration",
        "/tf",
        "/cameras/cam_a/detections",
        "/cameras/cam_b/detections",
        "/targets/robot",
        "/targets/person-1",
    }
    log_times = [m.log_time for _, _, m in messages]
    assert log_times == sorted(log_times)  # one time line across topics
    assert summary.statistics.message_count == len(messages) == 2 + 1 + 2 + 1 + 5 + 3 + 5

    # Detections: one ImageAnnotations per camera frame, a circle per stored row.
    frames = [json.loads(m.data) for _, m in by_topic["/cameras/cam_a/detections"]]
    assert [m.log_time for _, m in by_topic["/cameras/cam_a/detections"]] == [
        round(T0 * 1e9),
        round((T0 + 0.1) * 1e9),
    ]
    assert [[(c["position"]["x"], c["position"]["y"]) for c in f["circles"]] for f in frames] == [
        [(10.0, 20.0), (30.0, 40.0)],
        [(11.0, 21.0)],
    ]
    # Diameter: 3 standard deviations each side along the major axis: the larger eigenvalue
    # of [[4, 1], [1, 9]] is 6.5 + sqrt(6.25 + 1).
    assert frames[0]["circles"][1]["diameter"] == pytest.approx(
        6 * math.sqrt(6.5 + math.sqrt(7.25))
    )
    assert [t["text"] for t in frames[0]["texts"]] == ["robot", "person"]
    assert frames[0]["circles"][0]["timestamp"] == {"sec": int(T0), "nsec": 0}
    (b_frame,) = [json.loads(m.data) for _, m in by_topic["/cameras/cam_b/detections"]]
    assert b_frame["texts"][0]["text"] == "unknown" and b_frame["circles"][0]["position"] == {
        "x": 50.0,
        "y": 60.0,
    }

    # Tracks: a PoseInFrame per stored track point; robot poses as transforms too.
    poses = [json.loads(m.data) for _, m in by_topic["/targets/robot"]]
    assert [(p["pose"]["position"]["x"], p["pose"]["position"]["y"]) for p in poses] == [
        (x, y) for _, x, y in robot_points
    ]
    assert all(p["frame_id"] == "world" for p in poses)
    assert len(by_topic["/targets/person-1"]) == 3
    transforms = [json.loads(m.data) for _, m in by_topic["/tf"]]
    robot_tf = [tf for tf in transforms if tf["child_frame_id"] == "robot"]
    assert [tf["translation"]["x"] for tf in robot_tf] == [x for _, x, _ in robot_points]

    # The posed camera's frame in the world: the quaternion is its rotation.
    (camera_tf,) = [tf for tf in transforms if tf["child_frame_id"] == "cameras/cam_a"]
    q = camera_tf["rotation"]
    R_back = Rotation.from_quat([q["x"], q["y"], q["z"], q["w"]]).as_matrix()
    assert np.allclose(R_back, R, atol=1e-12)
    assert [camera_tf["translation"][k] for k in "xyz"] == [0.3, 0.3, 2.8]
    (calibration,) = [json.loads(m.data) for _, m in by_topic["/cameras/cam_a/calibration"]]
    assert calibration["K"] == [v for row in K for v in row] and calibration["D"] == DIST
    assert calibration["P"][:3] == K[0] and calibration["width"] == 640


def test_export_refuses_bad_and_too_long_ranges(client, admin):
    space = _space(client, admin, "home")
    url = f"/api/v1/spaces/{space}/export.mcap"
    bad = client.get(url, params={"since": 10.0, "until": 5.0}, headers=admin)
    assert bad.status_code == 422 and "after" in bad.text
    long = client.get(url, params={"since": 0.0, "until": 7200.0}, headers=admin)
    assert long.status_code == 422
    assert "at most 3600 s" in long.text and "INTSPACE_EXPORT_MAX_RANGE_S" in long.text
    assert client.get(url, params={"since": "nan"}, headers=admin).status_code == 422
    assert client.get(url, headers=admin).status_code == 422  # since is required
    missing = client.get("/api/v1/spaces/999/export.mcap", params={"since": 0, "until": 1})
    assert missing.status_code == 401  # no credential
    missing = client.get(
        "/api/v1/spaces/999/export.mcap", params={"since": 0, "until": 1}, headers=admin
    )
    assert missing.status_code == 404
    # An empty range is a valid, empty file.
    empty = client.get(url, params={"since": 0.0, "until": 1.0}, headers=admin)
    assert empty.status_code == 200
    summary, messages = _read(empty.content)
    assert messages == [] and summary.statistics.message_count == 0


def test_range_check_names_the_limit():
    assert check_range(0.0, 10.0, 60.0) is None
    assert "at most 60 s" in (check_range(0.0, 61.0, 60.0) or "")
    assert "finite" in (check_range(float("inf"), 1.0, 60.0) or "")
