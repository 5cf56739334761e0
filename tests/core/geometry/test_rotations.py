import cv2
import numpy as np
import pytest

from core.geometry.rotations import matrix_to_rotvec, nearest_rotation, rotvec_to_matrix, skew


def test_rotvec_to_matrix_matches_opencv_rodrigues():
    rng = np.random.default_rng(0)
    r = rng.normal(size=(200, 3))
    expected = np.array([cv2.Rodrigues(x)[0] for x in r])
    # Both evaluate the same closed form in double precision.
    assert np.abs(rotvec_to_matrix(r) - expected).max() < 1e-14


@pytest.mark.parametrize(
    "rvec",
    [
        [0.0, 0.0, 0.0],
        [1e-12, 0.0, 0.0],
        [0.3, -0.2, 0.1],
        [np.pi, 0.0, 0.0],  # a camera looking straight down is a half turn about x
        [0.0, np.pi - 1e-9, 0.0],
        [np.pi / np.sqrt(3)] * 3,
    ],
)
def test_matrix_to_rotvec_inverts_single_and_batched(rvec):
    R = rotvec_to_matrix(np.array(rvec))
    single = matrix_to_rotvec(R)
    assert single.shape == (3,)
    # Near pi the axis comes from R + I, accurate to about sqrt(eps) in the worst case.
    assert np.abs(rotvec_to_matrix(single) - R).max() < 1e-7
    batched = matrix_to_rotvec(np.stack([R, R]))
    assert np.allclose(batched, single[None], atol=1e-12)


def test_nearest_rotation_is_a_rotation_and_fixes_rotations():
    rng = np.random.default_rng(1)
    R = rotvec_to_matrix(rng.normal(size=(50, 3)))
    assert np.abs(nearest_rotation(R) - R).max() < 1e-12
    M = R + 0.05 * rng.normal(size=R.shape)
    Q = nearest_rotation(M)
    assert np.abs(Q @ np.swapaxes(Q, -1, -2) - np.eye(3)).max() < 1e-12
    assert np.allclose(np.linalg.det(Q), 1.0)


def test_skew_is_the_cross_product():
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(2, 10, 3))
    assert np.allclose((skew(a) @ b[..., None])[..., 0], np.cross(a, b))
