"""The registry's devices reaching the live scene through SceneSync: an applied projector
calibration moves the projector and its beam; the shown robot's arms are drawn at home."""

from __future__ import annotations

import numpy as np

from core.manipulation import default_arm
from core.sim import default_scene
from core.sim.projector import nominal_projector
from server.db.models import CalibrationRun
from server.scene import ProjectorEntry
from server.scene._geometry import matrix_from_quaternion
from server.schemas.manipulation import TWIN_ARM
from server.services.scene_sync import ROBOT_AGENT, SceneSync

# Poses go through float64 (matrix -> quaternion -> matrix ~1e-15); viser keeps line points as
# float32 (~1e-7 relative at a few metres).
POSE_TOL = 1e-9
POINT_TOL = 1e-5


def test_applying_a_projector_run_redraws_the_projector_at_its_new_pose(client, admin, scene):
    nominal = nominal_projector(default_scene()).T_world_base
    body = {"name": "laser", "width": 1, "height": 1, "T_world_projector": nominal.tolist()}
    created = client.post("/api/v1/projectors", json=body, headers=admin)
    assert created.status_code == 201, created.text
    projector_id = created.json()["id"]
    # The scene shows it as a planned path left it: the nominal mount, the beam on a spot.
    spot = [2.0, 3.0]
    scene.set_projector(ProjectorEntry("laser", nominal.tolist(), spot))
    # A succeeded calibration run that moved the mount by 4 cm and 1.5 degrees of yaw.
    c, s = np.cos(np.radians(1.5)), np.sin(np.radians(1.5))
    calibrated = nominal.copy()
    calibrated[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ nominal[:3, :3]
    calibrated[:3, 3] += [0.04, -0.01, 0.0]
    result = {
        "kind": "projector",
        "projector_id": projector_id,
        "T_world_projector": calibrated.tolist(),
        "tilt_offset_rad": 0.01,
        "rms_m": 0.01,
        "spots": 12,
    }
    with client.app.state.runtime.session_factory() as session:
        run = CalibrationRun(
            kind="projector", source="twin", status="succeeded", inputs={}, result=result
        )
        session.add(run)
        session.commit()
        run_id = run.id
    # The service's scene, as `intspace serve` has.
    client.app.state.runtime.scene_sync.scene = scene
    applied = client.post(f"/api/v1/calibration-runs/{run_id}/apply", headers=admin)
    assert applied.status_code == 200, applied.text
    assert applied.json()["T_world_projector"] == calibrated.tolist()
    assert scene.flush()
    find = scene.server.scene.get_handle_by_name
    frame = find("/navigation/projector")
    np.testing.assert_allclose(frame.position, calibrated[:3, 3], atol=POSE_TOL)
    np.testing.assert_allclose(
        matrix_from_quaternion(frame.wxyz), calibrated[:3, :3], atol=POSE_TOL
    )
    # The beam now leaves the calibrated mount for the same floor spot.
    beam = find("/navigation/beam").points
    np.testing.assert_allclose(beam[0, 0], calibrated[:3, 3], atol=POINT_TOL)
    np.testing.assert_allclose(beam[0, 1], [*spot, 0.0], atol=POINT_TOL)


def test_load_draws_the_shown_robots_arm_at_home(client, admin, scene):
    space = client.post("/api/v1/spaces", json={"name": "home"}, headers=admin).json()["id"]
    robot = client.post(
        "/api/v1/robots", json={"name": "twin robot", "space_id": space}, headers=admin
    ).json()["id"]
    arm = client.post(
        "/api/v1/arms", json={"robot_id": robot, "name": "puma"}, headers=admin
    ).json()
    with client.app.state.runtime.session_factory() as session:
        SceneSync(scene).load(session)
    scene.upsert_agent({"id": ROBOT_AGENT, "kind": "robot", "x": 1.0, "y": 1.0})
    assert scene.flush()
    view = scene.arms()[str(arm["id"])]
    assert view.agent == ROBOT_AGENT and view.name == "puma"
    np.testing.assert_allclose(view.q, TWIN_ARM["home"], atol=0.0)
    ee = view.frames[-1]
    T = np.eye(4)
    T[:3, :3] = matrix_from_quaternion(ee.wxyz)
    T[:3, 3] = ee.position
    np.testing.assert_allclose(T, default_arm().fk(TWIN_ARM["home"]), atol=POSE_TOL)
