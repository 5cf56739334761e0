"""Calibration runs through the API: Zhang's published data, chessboard photos, apply (once),
history, export, malformed uploads, runs checked against their camera, progress, and what a
restart or a shutdown does to queued and running runs."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from tests.support.chessboard_photos import K_TRUE, POSES, SQUARE_M, chessboard_photo
from tests.support.waiting import run_progress, wait_until, wait_while_advancing

INCH = 0.0254


def _zhang_views(data_dir: Path) -> tuple[list, list]:
    """Return Zhang's 5 views: model corners (N x 3, inches, Z = 0) and pixels (N x 2)."""
    model = np.loadtxt(data_dir / "Model.txt").reshape(-1, 2)
    object_points = np.column_stack([model, np.zeros(len(model))]).tolist()
    image_points = [
        np.loadtxt(data_dir / f"data{i}.txt").reshape(-1, 2).tolist() for i in range(1, 6)
    ]
    return [object_points] * 5, image_points


def _zhang_run(data_dir: Path, views: int = 5, **fields: Any) -> dict[str, Any]:
    """Return the body of an intrinsics run on the first `views` of Zhang's 5 views (640 x 480)
    with `fields` (its camera_id, options)."""
    object_points, image_points = _zhang_views(data_dir / "zhang1998")
    return {
        "kind": "intrinsics",
        **fields,
        "image_size": [640, 480],
        "object_points": object_points[:views],
        "image_points": image_points[:views],
    }


def _camera(client: TestClient, admin: dict, width: int = 640, height: int = 480) -> int:
    # Names are unique within a space: the second camera of a test is "pulnix-2".
    taken = client.get("/api/v1/cameras", headers=admin).json()["total"]
    name = "pulnix" if taken == 0 else f"pulnix-{taken + 1}"
    response = client.post(
        "/api/v1/cameras", json={"name": name, "width": width, "height": height}, headers=admin
    )
    assert response.status_code == 201, response.text
    return response.json()["id"]


def test_zhang_data_calibrates_apply_history_export(
    client, admin, run_waiter, shared_data_dir, tmp_path
):
    camera_id = _camera(client, admin)
    options = {"skew": True, "distortion": "k1k2"}
    body = _zhang_run(shared_data_dir, camera_id=camera_id, options=options)
    submitted = client.post("/api/v1/calibration-runs", json=body, headers=admin)
    assert submitted.status_code == 202, submitted.text
    assert submitted.json()["status"] in ("queued", "running", "succeeded")

    run = run_waiter(client, submitted.json()["id"])
    assert run["status"] == "succeeded", run["error"]
    result = run["result"]
    K = np.array(result["K"])
    # Zhang's published maximum-likelihood estimate (README of the data set), printed to 4-6
    # significant digits; the same model on the same points reproduces them to that precision.
    assert K[0, 0] == pytest.approx(832.5, abs=0.05)
    assert K[1, 1] == pytest.approx(832.53, abs=0.05)
    assert K[0, 2] == pytest.approx(303.959, abs=0.005)
    assert K[1, 2] == pytest.approx(206.585, abs=0.005)
    assert K[0, 1] == pytest.approx(0.204494, abs=0.005)
    assert result["dist"][:2] == pytest.approx([-0.228601, 0.190353], abs=5e-4)
    assert result["rms"] == pytest.approx(0.336, abs=0.01)
    assert len(result["per_view_rms"]) == 5
    assert result["std_intrinsics"]["fx"] > 0

    listed = client.get(f"/api/v1/calibration-runs?camera_id={camera_id}", headers=admin).json()
    assert listed["total"] == 1 and listed["items"][0]["id"] == run["id"]
    assert client.get("/api/v1/calibration-runs?camera_id=999", headers=admin).json()["total"] == 0

    assert run["attempts"] == 1 and run["progress"] == {"stage": "done", "fraction": 1.0}

    # Applying sets the camera's intrinsics and appends to its history, once: applying the
    # same run again answers the same camera and adds nothing.
    applied = [
        client.post(f"/api/v1/calibration-runs/{run['id']}/apply", headers=admin) for _ in range(2)
    ]
    assert [a.status_code for a in applied] == [200, 200], applied[1].text
    assert applied[0].json() == applied[1].json()
    camera = applied[1].json()
    assert camera["status"] == "calibrated" and camera["calibration_run_id"] == run["id"]
    assert np.allclose(camera["K"], K)
    history = client.get(f"/api/v1/cameras/{camera_id}/calibrations", headers=admin).json()
    assert history["total"] == 1 and history["items"][0]["calibration_run_id"] == run["id"]

    # The OpenCV export reads back through cv2.FileStorage with the same numbers.
    exported = client.get(f"/api/v1/cameras/{camera_id}/calibration.yaml", headers=admin)
    assert exported.status_code == 200
    path = tmp_path / "camera.yaml"
    path.write_text(exported.text)
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        assert np.allclose(storage.getNode("camera_matrix").mat(), K, rtol=1e-9)
        assert np.allclose(storage.getNode("distortion_coefficients").mat().ravel(), result["dist"])
        assert int(storage.getNode("image_width").real()) == 640
    finally:
        storage.release()
    ros = client.get(f"/api/v1/cameras/{camera_id}/calibration.yaml?format=ros", headers=admin)
    assert ros.status_code == 200 and "camera_matrix" in ros.text and "plumb_bob" in ros.text


def test_failed_run_reports_the_core_error(client, admin, run_waiter):
    camera_id = _camera(client, admin)
    # Three views of one collinear row of points: the homographies are undetermined.
    line = [[float(i), 0.0, 0.0] for i in range(6)]
    pixels = [[100.0 + 10 * i, 200.0] for i in range(6)]
    body = {
        "kind": "intrinsics",
        "camera_id": camera_id,
        "image_size": [640, 480],
        "object_points": [line] * 3,
        "image_points": [pixels] * 3,
    }
    submitted = client.post("/api/v1/calibration-runs", json=body, headers=admin)
    assert submitted.status_code == 202, submitted.text
    run = run_waiter(client, submitted.json()["id"])
    assert run["status"] == "failed" and run["result"] is None and run["error"]
    refused = client.post(f"/api/v1/calibration-runs/{run['id']}/apply", headers=admin)
    assert refused.status_code == 409


def test_mismatched_views_are_422(client, admin):
    camera_id = _camera(client, admin)
    body = {
        "kind": "intrinsics",
        "camera_id": camera_id,
        "image_size": [640, 480],
        "object_points": [[[0, 0, 0]] * 4] * 3,
        "image_points": [[[0, 0]] * 4] * 2,
    }
    response = client.post("/api/v1/calibration-runs", json=body, headers=admin)
    assert response.status_code == 422
    unknown_camera = {**body, "camera_id": 12345, "image_points": [[[0, 0]] * 4] * 3}
    response = client.post("/api/v1/calibration-runs", json=unknown_camera, headers=admin)
    assert response.status_code == 422
    assert response.json()["errors"][0]["field"] == "camera_id"


def test_upload_of_chessboard_photos_calibrates(client, admin, run_waiter):
    camera_id = _camera(client, admin)
    files = [
        ("files", (f"view{i}.png", chessboard_photo(r, t, seed=i), "image/png"))
        for i, (r, t) in enumerate(POSES)
    ]
    # A photo without the board (the board turned away: nothing but white) is skipped, named.
    _, blank = cv2.imencode(".png", np.full((480, 640), 255, np.uint8))
    files.insert(2, ("files", ("wall.png", blank.tobytes(), "image/png")))
    response = client.post(
        "/api/v1/calibration-runs/upload",
        data={
            "camera_id": str(camera_id),
            "chessboard": "9x6",
            "square": str(SQUARE_M),
            "distortion": "none",
            "skew": "false",
        },
        files=files,
        headers=admin,
    )
    assert response.status_code == 202, response.text
    run = run_waiter(client, response.json()["id"])
    assert run["status"] == "succeeded", run["error"]
    K = np.array(run["result"]["K"])
    # Rendered, noisy, interpolated corners: 1 % on the focal length and 3 px on the principal
    # point are far outside the errors of a correct pipeline and far inside those of a wrong
    # pattern size, square size or axis order.
    assert K[0, 0] == pytest.approx(700.0, rel=0.01)
    assert K[1, 1] == pytest.approx(700.0, rel=0.01)
    assert K[0, 2] == pytest.approx(320.0, abs=3.0)
    assert K[1, 2] == pytest.approx(240.0, abs=3.0)
    assert run["result"]["views_used"] == [0, 1, 3, 4]
    assert run["result"]["skipped"] == [
        {"index": 2, "filename": "wall.png", "reason": "no 9x6 chessboard found"}
    ]
    assert run["result"]["rms"] < 0.5


def test_runs_are_checked_against_their_camera_at_submit(client, admin, shared_data_dir):
    camera_id = _camera(client, admin, width=1280, height=720)
    body = _zhang_run(shared_data_dir, camera_id=camera_id)
    refused = client.post("/api/v1/calibration-runs", json=body, headers=admin)
    assert refused.status_code == 409, refused.text
    error = refused.json()["errors"][0]
    assert error["field"] == "image_size" and "640x480" in error["reason"]
    assert "1280x720" in error["reason"]

    photo = chessboard_photo(*POSES[0], seed=0)  # 640 x 480
    upload = _upload(client, admin, camera_id, [("files", ("a.png", photo, "image/png"))])
    assert upload.status_code == 409, upload.text
    assert upload.json()["errors"][0]["field"] == "files"
    # Nothing was queued by either.
    assert client.get("/api/v1/calibration-runs", headers=admin).json()["total"] == 0


def test_square_given_in_millimetres_is_refused_with_the_hint(client, admin):
    camera_id = _camera(client, admin)
    photo = chessboard_photo(*POSES[0], seed=0)
    refused = _upload(
        client, admin, camera_id, [("files", ("a.png", photo, "image/png"))], square="25"
    )
    assert refused.status_code == 422, refused.text
    error = refused.json()["errors"][0]
    assert error["field"] == "square" and "metres: did you mean 0.025" in error["reason"]


def _upload(client, admin, camera_id, files, **form):
    data = {"camera_id": str(camera_id), "chessboard": "9x6", "square": "0.03", **form}
    return client.post("/api/v1/calibration-runs/upload", data=data, files=files, headers=admin)


def test_malformed_uploads_are_4xx(make_settings, admin, run_waiter):
    with TestClient(create_app(make_settings(max_upload_file_bytes=2048))) as client:
        camera_id = _camera(client, admin)
        _, png = cv2.imencode(".png", np.zeros((8, 8), np.uint8))
        small = png.tobytes()

        not_image = _upload(client, admin, camera_id, [("files", ("a.png", b"hello", "image/png"))])
        assert not_image.status_code == 415, not_image.text
        assert not_image.json()["errors"][0]["field"] == "files.0"

        big = _upload(
            client, admin, camera_id, [("files", ("big.bin", b"\x89PNG" * 1000, "image/png"))]
        )
        assert big.status_code == 413, big.text

        empty = _upload(client, admin, camera_id, [("files", ("e.png", b"", "image/png"))])
        assert empty.status_code == 415

        no_files = _upload(client, admin, camera_id, [])
        assert no_files.status_code == 422

        bad_pattern = _upload(
            client,
            admin,
            camera_id,
            [("files", ("a.png", small, "image/png"))],
            chessboard="nine by six",
        )
        assert bad_pattern.status_code == 422
        assert bad_pattern.json()["errors"][0]["field"] == "chessboard"

        bad_square = _upload(
            client, admin, camera_id, [("files", ("a.png", small, "image/png"))], square="-1"
        )
        assert bad_square.status_code == 422

        _, other = cv2.imencode(".png", np.zeros((9, 8), np.uint8))
        mixed = _upload(
            client,
            admin,
            camera_id,
            [
                ("files", ("a.png", small, "image/png")),
                ("files", ("b.png", other.tobytes(), "image/png")),
            ],
        )
        assert mixed.status_code == 422

        unknown = _upload(client, admin, 999, [("files", ("a.png", small, "image/png"))])
        assert unknown.status_code == 422

        no_token = client.post("/api/v1/calibration-runs/upload", data={"camera_id": "1"})
        assert no_token.status_code == 401

        # A board that is not in the photo (of a camera of its size): the run fails with the
        # core's reason, naming the photo.
        tiny_camera = _camera(client, admin, width=8, height=8)
        blank = _upload(client, admin, tiny_camera, [("files", ("a.png", small, "image/png"))])
        assert blank.status_code == 202, blank.text
        run = run_waiter(client, blank.json()["id"])
        assert run["status"] == "failed" and run["error"].startswith("PatternNotFound")
        assert "a.png: " in run["error"]


def _set_run(settings, run_id: int, **values) -> None:
    """Write columns of a run directly, as a worker of another process would have."""
    from sqlalchemy import update

    from server.db.models import CalibrationRun
    from server.db.session import make_engine, make_session_factory

    engine = make_engine(settings.resolved_database_url, pool_size=1)
    try:
        with make_session_factory(engine)() as session:
            session.execute(
                update(CalibrationRun).where(CalibrationRun.id == run_id).values(**values)
            )
            session.commit()
    finally:
        engine.dispose()


def test_applying_a_network_run_twice_changes_each_camera_once(make_settings, admin):
    from server.db.models import CalibrationRun
    from server.db.session import make_engine, make_session_factory

    settings = make_settings(run_executor="external")
    with TestClient(create_app(settings)) as client:
        ids = [_camera(client, admin) for _ in range(2)]
        pose = np.eye(4)
        pose[:3, 3] = [1.0, 2.0, 2.5]
        # What a network run stores for each camera it calibrated (the fields apply reads).
        cameras = [
            {
                "name": f"cam{i}",
                "camera_id": camera_id,
                "K": K_TRUE.tolist(),
                "dist": [0.01, 0.0, 0.0, 0.0, 0.0],
                "T_world_camera": pose.tolist(),
                "rms": 0.2,
                "image_size": [640, 480],
            }
            for i, camera_id in enumerate(ids)
        ]
        engine = make_engine(settings.resolved_database_url, pool_size=1)
        with make_session_factory(engine)() as session:
            run = CalibrationRun(
                kind="network",
                source="twin",
                status="succeeded",
                inputs={},
                options={},
                result={"kind": "network", "cameras": cameras},
            )
            session.add(run)
            session.commit()
            run_id = run.id
        engine.dispose()
        applied = [
            client.post(f"/api/v1/calibration-runs/{run_id}/apply", headers=admin) for _ in range(2)
        ]
        assert [a.status_code for a in applied] == [200, 200], applied[1].text
        assert applied[0].json() == applied[1].json()
        assert [c["id"] for c in applied[1].json()] == ids
        for camera_id in ids:
            history = client.get(f"/api/v1/cameras/{camera_id}/calibrations", headers=admin)
            assert history.json()["total"] == 1
            camera = client.get(f"/api/v1/cameras/{camera_id}", headers=admin).json()
            assert camera["calibration_run_id"] == run_id
            assert np.allclose(camera["T_world_camera"], pose)


def test_restart_keeps_queued_runs_and_requeues_only_expired_claims(
    make_settings, admin, run_waiter, shared_data_dir
):
    from datetime import timedelta

    from server.db.base import utcnow
    from server.services.jobs import LeasePolicy

    body = _zhang_run(shared_data_dir, views=3)
    # With external workers the API only queues: four runs, three of which a worker of another
    # process had claimed: one whose worker died (lease expired), one that died as often as
    # it may, and one whose worker is alive (lease still running).
    settings = make_settings(run_executor="external")
    with TestClient(create_app(settings)) as client:
        camera_id = _camera(client, admin)
        ids = [
            client.post(
                "/api/v1/calibration-runs", json={**body, "camera_id": camera_id}, headers=admin
            ).json()["id"]
            for _ in range(4)
        ]
    queued, expired, exhausted, alive = ids
    past, future = utcnow() - timedelta(seconds=5), utcnow() + timedelta(hours=1)
    claimed = {"status": "running", "started_at": past, "lease_owner": "elsewhere:1:0"}
    _set_run(settings, expired, **claimed, attempts=1, lease_expires_at=past)
    attempts = LeasePolicy().max_attempts
    _set_run(settings, exhausted, **claimed, attempts=attempts, lease_expires_at=past)
    _set_run(settings, alive, **claimed, attempts=1, lease_expires_at=future)

    with TestClient(create_app(make_settings())) as client:
        # The queued run stayed queued and is executed; the expired claim went back to the
        # queue and is executed on its second attempt.
        run = run_waiter(client, queued)
        assert run["status"] == "succeeded" and run["attempts"] == 1, run["error"]
        run = run_waiter(client, expired)
        assert run["status"] == "succeeded" and run["attempts"] == 2, run["error"]
        run = client.get(f"/api/v1/calibration-runs/{exhausted}", headers=admin).json()
        assert run["status"] == "failed" and run["result"] is None
        assert "worker stopped" in run["error"] and f"{attempts} time(s)" in run["error"]
        # A live claim of another worker is left alone.
        run = client.get(f"/api/v1/calibration-runs/{alive}", headers=admin).json()
        assert run["status"] == "running" and run["attempts"] == 1


def test_worker_claims_queued_runs(make_settings, admin, shared_data_dir):
    from server.db.session import make_engine, make_session_factory
    from server.services.jobs import LeasePolicy, claim_next
    from server.services.runs import RUNS, execute_claimed_run

    settings = make_settings(run_executor="external")
    with TestClient(create_app(settings)) as client:
        camera_id = _camera(client, admin)
        body = _zhang_run(shared_data_dir, views=3, camera_id=camera_id)
        run_id = client.post("/api/v1/calibration-runs", json=body, headers=admin).json()["id"]

        engine = make_engine(settings.resolved_database_url, pool_size=1)
        factory = make_session_factory(engine)
        policy = LeasePolicy()
        with factory() as session:
            assert claim_next(session, RUNS, "w1", policy) == run_id
        with factory() as session:
            assert claim_next(session, RUNS, "w2", policy) is None  # nothing else is queued
        assert execute_claimed_run(factory, run_id, "w2") is None  # not its claim: no write
        assert execute_claimed_run(factory, run_id, "w1") == "succeeded"
        engine.dispose()
        run = client.get(f"/api/v1/calibration-runs/{run_id}", headers=admin).json()
        assert run["status"] == "succeeded" and run["started_at"] and run["finished_at"]


def test_progress_is_reported_and_shutdown_hands_the_run_back(make_settings, admin, monkeypatch):
    import time

    from server.services.calibration import intrinsics

    stopped = threading.Event()

    def slow_calibration(inputs, options, progress):
        # A long run reporting its progress; each report is a point where it can be stopped.
        try:
            for k in range(400):
                progress("slow stage", k / 400)
                time.sleep(0.025)  # time passes between the reports of a long computation
            raise AssertionError("the run should have been stopped at shutdown")
        finally:
            stopped.set()

    monkeypatch.setattr(intrinsics, "calibrate_from_correspondences", slow_calibration)
    body = {
        "kind": "intrinsics",
        "image_size": [640, 480],
        "object_points": [[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]] * 3,
        "image_points": [[[0, 0], [10, 0], [10, 10], [0, 10]]] * 3,
    }
    with TestClient(create_app(make_settings())) as client:
        camera_id = _camera(client, admin)
        run_id = client.post(
            "/api/v1/calibration-runs", json={**body, "camera_id": camera_id}, headers=admin
        ).json()["id"]
        run = wait_while_advancing(
            lambda: client.get(f"/api/v1/calibration-runs/{run_id}", headers=admin).json(),
            done=lambda run: (
                run["status"] == "running" and (run["progress"] or {}).get("fraction", 0) > 0.05
            ),
            progress=run_progress,
            stalled_after_s=10,
            poll_s=0.05,
            what="the run (to be past 5 %)",
        )
        assert run["progress"]["stage"] == "slow stage" and run["progress"]["fraction"] < 1
        assert run["lease_expires_at"] is not None
    # The service stopped with the run computing: the run is back in the queue (its attempt
    # counted) and the attempt, stopped at its next progress report, wrote nothing.
    wait_until(stopped.is_set, what="the attempt stopping", stalled_after_s=5)
    with TestClient(create_app(make_settings(run_executor="external"))) as client:
        run = client.get(f"/api/v1/calibration-runs/{run_id}", headers=admin).json()
    assert run["status"] == "queued" and run["attempts"] == 1
    assert run["result"] is None and run["error"] is None and run["progress"] is None


def test_network_drive_result_is_stored_and_read_with_its_diagnostics():
    # The service's network run on the twin (a drive shortened by the user's `minutes`, its
    # programme scaled with it: 16 planned stops; no accuracy study): what it stores reads back
    # through the run schema with the fields, labelled.
    from core.sim import default_scene
    from server.schemas.calibration import NetworkRunResult
    from server.services.calibration import network_calibration_drive

    result = network_calibration_drive(default_scene(), 2, minutes=2.5, study=False)
    read = NetworkRunResult.model_validate(result)
    assert read.drive_s is not None and 60 < read.drive_s <= 150
    assert read.sigma_px is not None and 0 < read.sigma_px < 1.0
    assert read.intrinsics_from and "chessboard" in read.intrinsics_from
    assert read.rms_px is not None and read.rms_whitened is not None
    assert len(read.pose_rms_px) == read.poses
    for cam in read.cameras:
        assert cam.detections is not None and cam.detections >= cam.poses_seen
        assert len(cam.pose_residuals) == cam.detections - cam.outliers
        # Pooled per camera: the residuals' RMS is the camera's rms (pixels).
        r = np.array(cam.pose_residuals)[:, 1:]
        assert abs(np.sqrt(np.mean(np.sum(r**2, axis=1))) - cam.rms) < 1e-9
        assert cam.std["f_px"] > 0 and "cx" in cam.std["parameters"]
        assert cam.bound is not None and cam.bound.position_m > 0
        assert abs(cam.errors.focal_pct) < 1.0
