"""Pose, frustum and floor-polygon helpers of the scene, against independent references."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.errors import InvalidInput
from core.geometry.polygon import signed_area
from server.scene._geometry import (
    as_polygon,
    frustum_from_intrinsics,
    matrix_from_quaternion,
    pose_from_transform,
    quaternion_from_matrix,
    triangulate_polygon,
)


def test_quaternion_matches_scipy_for_random_and_half_turn_rotations():
    rng = np.random.default_rng(0)
    mats = list(Rotation.random(500, random_state=rng).as_matrix())
    # Half turns and near half turns: w ~ 0, the hard case for trace-based formulas.
    for axis in rng.normal(size=(20, 3)):
        axis /= np.linalg.norm(axis)
        for angle in (math.pi, math.pi - 1e-9):
            mats.append(Rotation.from_rotvec(axis * angle).as_matrix())
    for R in mats:
        q = quaternion_from_matrix(R)
        ref = np.roll(Rotation.from_matrix(R).as_quat(), 1)  # scipy is (x, y, z, w)
        ref = ref if ref[0] >= 0 else -ref
        # q and -q are the same rotation; at w = 0 both signs are valid, so compare up to sign.
        err = min(np.max(np.abs(q - ref)), np.max(np.abs(q + ref)))
        assert err < 1e-12
        np.testing.assert_allclose(matrix_from_quaternion(q), R, atol=1e-13)


def test_pose_from_transform_refuses_what_is_not_rigid():
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    pose = pose_from_transform(T)
    assert pose.wxyz == (1.0, 0.0, 0.0, 0.0) and pose.position == (1.0, 2.0, 3.0)
    mirrored = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(InvalidInput, match="rotation"):
        pose_from_transform(mirrored)
    projective = np.eye(4)
    projective[3, 0] = 0.1
    with pytest.raises(InvalidInput, match="last row"):
        pose_from_transform(projective)
    with pytest.raises(InvalidInput, match="4x4"):
        pose_from_transform(np.eye(3))


def test_frustum_field_of_view_from_intrinsics():
    # fy = h / 2 gives a 90 degree vertical field of view.
    K = [[300.0, 0.0, 320.0], [0.0, 240.0, 240.0], [0.0, 0.0, 1.0]]
    f = frustum_from_intrinsics(K, 640, 480)
    assert f.fov == pytest.approx(math.pi / 2, abs=1e-15)
    assert f.aspect == pytest.approx(4 / 3)
    assert frustum_from_intrinsics(None, 1920, 1080).fov == pytest.approx(math.radians(60))
    with pytest.raises(InvalidInput):
        frustum_from_intrinsics(K, 0, 480)


@pytest.mark.parametrize(
    "polygon",
    [
        [[0, 0], [6, 0], [6, 5], [3, 5], [3, 3], [0, 3]],  # L-shaped, counter-clockwise
        [[0, 3], [3, 3], [3, 5], [6, 5], [6, 0], [0, 0]],  # the same, clockwise
        [[0, 0], [4, 0], [4, 4], [3, 4], [3, 1], [1, 1], [1, 4], [0, 4]],  # U-shaped
        [[0, 0], [2, 0], [2, 2], [0, 2], [0, 0]],  # closed ring repeating its first vertex
    ],
)
def test_triangulation_covers_the_polygon_exactly(polygon):
    p = as_polygon(polygon, "room")
    tris = triangulate_polygon(p)
    assert tris.shape == (len(p) - 2, 3)
    a, b, c = p[tris[:, 0]], p[tris[:, 1]], p[tris[:, 2]]
    areas = 0.5 * (
        (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    )
    # Every triangle is counter-clockwise and non-degenerate, and together they tile the area.
    assert np.all(areas > 0)
    assert areas.sum() == pytest.approx(abs(signed_area(p)), abs=1e-12)
    # Every triangle's centroid lies inside the polygon (no ear was cut across a notch).
    centroids = (a + b + c) / 3.0
    contour = p.astype(np.float32).reshape(-1, 1, 2)
    for x, y in centroids:
        assert cv2.pointPolygonTest(contour, (float(x), float(y)), False) > 0
