"""Groups of single detections located on their own planes (core.localization.locate_groups)."""

from __future__ import annotations

import numpy as np
import pytest
from localization_scene import floor_points, make_cameras

from core.localization import PointStatus
from core.localization.groups import DuplicateView, locate_groups


def _detections(cameras, points, rng):
    """Return (camera, group, pixels) of every camera's view of every point it sees, shuffled."""
    cam, group, pix = [], [], []
    for c, camera in enumerate(cameras):
        seen = np.flatnonzero(camera.in_view(points))
        cam += [c] * seen.size
        group += seen.tolist()
        pix.append(camera.project(points[seen]))
    order = rng.permutation(len(cam))
    return np.array(cam)[order], np.array(group)[order], np.concatenate(pix)[order]


def test_groups_at_several_heights_are_found_where_they_are():
    rng = np.random.default_rng(3)
    cameras = make_cameras()
    points = np.concatenate([floor_points(rng, 4, 0.9), floor_points(rng, 3, 1.6)])
    cam, group, pix = _detections(cameras, points, rng)
    cov = np.tile(np.eye(2) * 0.25, (cam.size, 1, 1))
    found = locate_groups(cameras, cam, group, points[:, 2], pix, cov)
    assert np.all(found.status == PointStatus.OK)
    # Noise-free pixels: the ML point is the true one up to the solver's convergence (its
    # steps stop below a micrometre on this scene, far below the centimetres that matter).
    np.testing.assert_allclose(found.xy, points[:, :2], atol=1e-6)
    assert found.n_cameras.tolist() == np.bincount(group, minlength=len(points)).tolist()
    # Each a 2x2 covariance, symmetric positive definite, of the 0.5 px noise through the
    # cameras: millimetres, not metres.
    assert np.all(np.linalg.eigvalsh(found.cov) > 0)
    assert np.all(np.sqrt(found.cov[:, [0, 1], [0, 1]]) < 0.05)


def test_a_camera_seeing_a_group_twice_is_refused_naming_its_first_detection():
    cameras = make_cameras(2)
    pixels = np.full((3, 2), 400.0)
    cov = np.tile(np.eye(2), (3, 1, 1))
    with pytest.raises(DuplicateView) as caught:
        locate_groups(cameras, [1, 0, 1], [0, 0, 0], [1.0], pixels, cov)
    assert caught.value.index == 0
