"""The twin's installed calibration: what the service starts from is the network calibration's
own output (made again here and compared), and it is scored against the twin."""

from __future__ import annotations

import numpy as np

from core.sim import default_scene
from core.sim.installation import (
    calibrate_installation,
    installed_calibration,
    scene_fingerprint,
)
from core.sim.render import camera_model


def test_shipped_calibration_is_the_drive_made_again() -> None:
    scene = default_scene()
    shipped = installed_calibration(scene)
    assert shipped.source == "shipped"
    again = calibrate_installation(scene, shipped.seed)
    assert [c.name for c in again.cameras] == [c.name for c in shipped.cameras]
    ref_a, ref_b = again.cameras[0].T_world_camera, shipped.cameras[0].T_world_camera
    for a, b in zip(again.cameras, shipped.cameras, strict=True):
        # The drive is deterministic for its seed; the file keeps floats to full precision, so
        # only the solvers' last bits (BLAS threading) may differ: the network itself (each
        # camera's intrinsics and its pose relative to the first) agrees to 1e-9 here.
        np.testing.assert_allclose(a.K, b.K, rtol=1e-7)
        np.testing.assert_allclose(a.dist, b.dist, atol=1e-7)
        np.testing.assert_allclose(
            np.linalg.inv(ref_a) @ a.T_world_camera,
            np.linalg.inv(ref_b) @ b.T_world_camera,
            atol=1e-7,
        )
        # Its move into the world comes from the signpost tour, a closed loop: the robot drives
        # on its own estimates, so a last-bit difference (another processor's BLAS kernels)
        # can change the frame a signpost is read in, and the tour goes on with other frames.
        # Made again here with OpenBLAS's AVX2 kernels signpost 26 was read at 45.6 s, with its
        # Sandybridge kernels at 41.4 s, and the registration moved by up to 1.9 mm and 0.020
        # deg (5 um and 2e-4 deg when the tour stays the same): a fifth of the registration's
        # own deviation (~1 cm, 0.16 deg). What a processor may change is bounded at half that
        # deviation (5 mm, 0.08 deg); the network above, which the tour does not move, still
        # holds the file to 1e-7.
        d = np.linalg.inv(b.T_world_camera) @ a.T_world_camera
        assert np.linalg.norm(d[:3, 3]) < 5e-3, a.name
        cos = np.clip((np.trace(d[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
        assert np.degrees(np.arccos(cos)) < 0.08, a.name


def test_installed_cameras_against_the_twin() -> None:
    scene = default_scene()
    cal = installed_calibration(scene)
    truth = {c.name: camera_model(c) for c in scene.cameras}
    assert not cal.rejected
    for cam in cal.cameras:
        true = truth[cam.name]
        # Spec 02's goals: focal within 1 %; registered to the world by the signpost tour, the
        # home's frame no longer rests on the odometry's heading (it put cameras up to 8.6 cm
        # and 0.83 deg off): measured 0.3-0.6 cm and 0.02-0.12 deg (the drive with the mast
        # raised, the marker model predicting the area centroid of the disc's image; 0.5-1.1 cm
        # with its ellipse centre), asserted at the goal's 2 cm and 0.3 deg.
        assert abs(cam.K[0, 0] / true.K[0, 0] - 1.0) < 0.01, cam.name
        err = np.linalg.norm(cam.T_world_camera[:3, 3] - true.T_world_camera[:3, 3])
        assert err < 0.02, (cam.name, err)
        dR = cam.T_world_camera[:3, :3].T @ true.T_world_camera[:3, :3]
        angle = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
        assert angle < 0.3, (cam.name, angle)
        assert not np.allclose(cam.K, true.K), cam.name  # an estimate, not the truth


def test_another_home_gets_its_own_drive() -> None:
    scene = default_scene()
    moved = scene.model_copy(update={"name": "another home"})
    assert scene_fingerprint(moved) != scene_fingerprint(scene)
    walkers_only = scene.model_copy(update={"people": ()})
    assert scene_fingerprint(walkers_only) == scene_fingerprint(scene)
