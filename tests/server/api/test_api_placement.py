"""Placing a real camera through the API (floor points -> pose, stored as a run, applied once),
its node's latest frame, and a detector's boxes as observations."""

from __future__ import annotations

import json
import time

import cv2
import numpy as np
import pytest
from sqlalchemy import create_engine, text

from core.localization import NetworkCamera, box_foot, cut_mask, foot_on_axis
from core.localization.appearance import APPEARANCE_SIZE

K = [[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]]
SIZE = (640, 480)


def _true_camera() -> NetworkCamera:
    return NetworkCamera.looking_at(K, None, [0.2, 0.3, 2.6], [2.5, 1.8, 0.0], SIZE)


def _points(n: int = 9, seed: int = 4) -> tuple[np.ndarray, np.ndarray]:
    cam = _true_camera()
    rng = np.random.default_rng(seed)
    floor = rng.uniform([0.8, 0.8], [4.5, 3.5], (4 * n, 2))
    X = np.c_[floor, np.zeros(len(floor))]
    keep = cam.in_view(X)
    X = X[keep][:n]
    return X, cam.project(X) + rng.normal(0, 0.5, (n, 2))


def _camera(client, admin, **extra) -> int:
    body = {"name": f"porch-{time.monotonic_ns()}", "width": SIZE[0], "height": SIZE[1], **extra}
    response = client.post("/api/v1/cameras", json=body, headers=admin)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def _body(X, uv, **extra):
    points = [{"pixel": p.tolist(), "floor": x[:2].tolist()} for p, x in zip(uv, X, strict=True)]
    return {"points": points, **extra}


def test_placement_finds_the_wrong_pair_is_applied_once_and_refuses_degenerate_points(
    client, admin
):
    cid = _camera(client, admin)
    X, uv = _points()
    uv[3] += [30.0, -20.0]  # a click on the neighbouring tile's corner
    answer = client.post(f"/api/v1/cameras/{cid}/placement", json=_body(X, uv), headers=admin)
    assert answer.status_code == 201, answer.text
    placed = answer.json()
    assert placed["rejected"] == [3]
    assert placed["residuals_px"][3] > 20 and max(np.delete(placed["residuals_px"], 3)) < 2.5
    std = placed["std"]
    # The true focal length (600 px) and camera centre within 4 reported standard deviations.
    assert abs(placed["K"][0][0] - 600.0) < 4 * std["f_px"]
    centre = np.array(placed["T_world_camera"])[:3, 3]
    assert np.all(np.abs(centre - [0.2, 0.3, 2.6]) < 4 * np.array(std["position_m"]) + 1e-3)
    assert len(std["rotation_deg"]) == 3

    # Not applied yet: the camera is unplaced; the run is a stored calibration run.
    assert client.get(f"/api/v1/cameras/{cid}", headers=admin).json()["T_world_camera"] is None
    run = client.get(f"/api/v1/calibration-runs/{placed['run_id']}", headers=admin).json()
    assert (run["kind"], run["status"]) == ("placement", "succeeded")
    assert run["result"]["rejected"] == [3]
    for _ in range(2):  # applying twice changes nothing the second time
        applied = client.post(f"/api/v1/calibration-runs/{placed['run_id']}/apply", headers=admin)
        assert applied.status_code == 200, applied.text
    camera = applied.json()
    assert camera["T_world_camera"] == placed["T_world_camera"] and camera["K"] == placed["K"]
    history = client.get(f"/api/v1/cameras/{cid}/calibrations", headers=admin).json()
    assert history["total"] == 1

    # Degenerate points are refused with the reason, and store nothing.
    few = client.post(f"/api/v1/cameras/{cid}/placement", json=_body(X[:3], uv[:3]), headers=admin)
    assert few.status_code == 422 and "at least 4" in few.json()["detail"]
    line = np.stack([np.linspace(1, 4, 6), np.linspace(1, 3, 6), np.zeros(6)], 1)
    on_line = client.post(
        f"/api/v1/cameras/{cid}/placement",
        json=_body(line, _true_camera().project(line)),
        headers=admin,
    )
    assert on_line.status_code == 422 and "line" in on_line.json()["detail"]
    missing = client.post("/api/v1/cameras/999999/placement", json=_body(X, uv), headers=admin)
    assert missing.status_code == 404
    runs = client.get("/api/v1/calibration-runs", headers=admin).json()
    assert runs["total"] == 1  # the placement above; nothing for refused input


def test_placement_with_known_intrinsics_applies_at_once(client, admin):
    cid = _camera(client, admin, K=K, dist=[0.0] * 5)
    X, uv = _points(6, seed=9)
    answer = client.post(
        f"/api/v1/cameras/{cid}/placement", json=_body(X, uv, apply=True), headers=admin
    )
    assert answer.status_code == 201, answer.text
    placed = answer.json()
    assert placed["std"]["f_px"] is None and placed["K"] == K
    camera = client.get(f"/api/v1/cameras/{cid}", headers=admin).json()
    assert camera["T_world_camera"] == placed["T_world_camera"] and camera["K"] == K
    assert np.linalg.norm(np.array(camera["T_world_camera"])[:3, 3] - [0.2, 0.3, 2.6]) < 0.05


def _jpeg(size=SIZE, value=90) -> bytes:
    image = np.full((size[1], size[0], 3), value, np.uint8)
    cv2.circle(image, (100, 100), 30, (0, 0, 255), -1)
    return cv2.imencode(".jpg", image)[1].tobytes()


def test_a_node_uploads_the_latest_frame_once_a_second(client, admin):
    cid = _camera(client, admin)
    other = _camera(client, admin)
    token = client.post(
        "/api/v1/tokens",
        json={"name": "node", "scopes": ["ingest"], "camera_ids": [cid]},
        headers=admin,
    ).json()["token"]
    node = {"Authorization": f"Bearer {token}", "Content-Type": "image/jpeg"}
    assert client.get(f"/api/v1/cameras/{cid}/frame.jpg", headers=admin).status_code == 404
    jpeg = _jpeg()
    put = client.put(f"/api/v1/cameras/{cid}/frame", content=jpeg, headers=node)
    assert put.status_code == 204, put.text
    again = client.put(f"/api/v1/cameras/{cid}/frame", content=_jpeg(value=10), headers=node)
    assert again.status_code == 429 and int(again.headers["Retry-After"]) >= 1
    served = client.get(f"/api/v1/cameras/{cid}/frame.jpg", headers=admin)
    assert served.status_code == 200 and served.content == jpeg
    foreign = client.put(f"/api/v1/cameras/{other}/frame", content=jpeg, headers=node)
    assert foreign.status_code == 403
    writer = {**admin, "Content-Type": "image/jpeg"}
    small = client.put(f"/api/v1/cameras/{other}/frame", content=_jpeg((320, 240)), headers=writer)
    assert small.status_code == 422 and "320x240" in small.json()["detail"]
    png = cv2.imencode(".png", np.zeros((480, 640, 3), np.uint8))[1].tobytes()
    not_jpeg = client.put(f"/api/v1/cameras/{other}/frame", content=png, headers=writer)
    assert not_jpeg.status_code == 415
    cut_short = client.put(f"/api/v1/cameras/{other}/frame", content=jpeg[:300], headers=writer)
    assert cut_short.status_code == 422
    assert client.get(f"/api/v1/cameras/{other}/frame.jpg", headers=admin).status_code == 404
    # A deleted camera's frame goes with it.
    assert client.delete(f"/api/v1/cameras/{cid}", headers=admin).status_code == 204
    assert client.get(f"/api/v1/cameras/{cid}/frame.jpg", headers=admin).status_code == 404


def _json(value):
    # SQLite hands a JSON column back as text, PostgreSQL's driver as the decoded value.
    return json.loads(value) if isinstance(value, str) else value


def _placed_camera(client, admin, **extra) -> int:
    cam = _true_camera()
    return _camera(
        client, admin, K=K, dist=[0.0] * 5, T_world_camera=cam.T_world_camera.tolist(), **extra
    )


def test_boxes_are_stored_with_score_and_cut_and_refused_when_bad(client, admin, database_url):
    cid = _placed_camera(client, admin, score_threshold=0.4)
    now = time.time()
    # A standing person about 2.6 m from the camera, as a detector boxes them: 0.4 m wide, feet
    # at (320, 260), the head above the image (this camera looks down), so the box stops at 0.
    box = {"camera_id": cid, "t": now, "box": [275.0, 0.0, 365.0, 260.0], "score": 0.9}
    # The box's look (core.localization.appearance): two parts' histograms, half each.
    look = [0.0] * APPEARANCE_SIZE
    look[3] = look[APPEARANCE_SIZE // 2 + 7] = 0.5
    batch = [
        {**box, "appearance": look},
        {**box, "score": 0.3},  # under the camera's 0.4: dropped
        {**box, "t": now + 0.1, "cut": ["bottom"]},  # stored, not tracked
        {**box, "t": now + 0.2, "cut": ["left", "top"]},
    ]
    answer = client.post("/api/v1/observations", json={"observations": batch}, headers=admin)
    assert answer.status_code == 200, answer.text
    # Three stored; two camera frames reach the tracker (the cut-bottom one does not).
    assert (answer.json()["stored"], answer.json()["frames"]) == (3, 2)
    engine = create_engine(database_url)
    with engine.connect() as connection:
        rows = connection.execute(
            text("SELECT u, v, cxx, cyy, kind, box, score, cut FROM detections ORDER BY t")
        ).all()
        looks = connection.execute(text("SELECT appearance FROM detections ORDER BY t")).all()
    engine.dispose()
    assert len(rows) == 3
    assert _json(looks[0][0]) == look and [r[0] for r in looks[1:]] == [None, None]
    u, v, cxx, cyy, kind, stored_box, score, _ = rows[0]
    assert (kind, score) == ("person", 0.9)
    # The foot the service measured: the one core function's (box_foot, then moved to the
    # body's axis with the camera's geometry, the cut sides' edges unused), stored as the
    # detection's pixel.
    cut = cut_mask([[], ["left", "top"]])
    expected = foot_on_axis(
        [box["box"]] * 2, box_foot([box["box"]] * 2, cut), _true_camera(), cut=cut
    )
    np.testing.assert_allclose([u, v, cxx, cyy], [*expected.pixel[0], *np.diag(expected.cov[0])])
    # The box's bottom centre (320, 260) moved up the image: the axis is behind the near edge.
    assert abs(u - 320.0) < 15 and 220 < v < 259
    assert _json(stored_box) == box["box"]
    cuts = [_json(r[7]) for r in rows]
    assert cuts == [[], ["bottom"], ["left", "top"]]
    # Cut on the left: sigma_u widened to half the visible width, so more u variance.
    assert rows[2][2] == pytest.approx(expected.cov[1, 0, 0]) and rows[2][2] > 4 * cxx

    bad = {
        "box": ({**box, "box": [340.0, 150.0, 300.0, 260.0]}, "observations.0.box"),
        "range": ({**box, "box": [300.0, 150.0, 5000.0, 260.0]}, "observations.0.box"),
        "side": ({**box, "cut": ["under"]}, "observations.0.cut.0"),
        "both": ({**box, "pixel": [320.0, 260.0]}, "observations.0"),
        "neither": ({"camera_id": cid, "t": now}, "observations.0"),
        "score": ({**box, "score": 1.5}, "observations.0.score"),
        "look length": ({**box, "appearance": look[:-1]}, "observations.0.appearance"),
        "look sign": ({**box, "appearance": [-0.5, *look[1:]]}, "observations.0.appearance.0"),
        "look sum": ({**box, "appearance": [0.5] * APPEARANCE_SIZE}, "observations.0"),
        "look pixel": (
            {"camera_id": cid, "t": now, "pixel": [320.0, 260.0], "appearance": look},
            "observations.0",
        ),
    }
    for name, (observation, field) in bad.items():
        refused = client.post(
            "/api/v1/observations", json={"observations": [observation]}, headers=admin
        )
        assert refused.status_code == 422, (name, refused.text)
        fields = [e["field"] for e in refused.json().get("errors", [])]
        assert any(f.endswith(field) for f in fields), (name, refused.json())
