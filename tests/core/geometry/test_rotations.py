import cv2
import numpy as np
import pytest

from core.errors import InvalidInput
from core.geometry.rotations import (
    matrix_to_quaternion,
    matrix_to_rotvec,
    nearest_rotation,
    quaternion_to_matrix,
    rotvec_to_matrix,
    skew,
    wrap_angle,
)


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


def test_quaternions_match_scipy_single_and_batched():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(1)
    q = rng.normal(size=(500, 4))
    q[:4] = np.eye(4)  # the identity and the three half turns pivot on each branch
    q[4] = [0.0, 1.0, 1.0, 0.0]  # a half turn about a diagonal: w = 0
    R = Rotation.from_quat(q / np.linalg.norm(q, axis=1, keepdims=True)).as_matrix()
    # Both evaluate closed forms in double precision on unit quaternions.
    np.testing.assert_allclose(quaternion_to_matrix(q), R, atol=1e-14)
    np.testing.assert_allclose(quaternion_to_matrix(q[7]), R[7], atol=1e-14)
    back = matrix_to_quaternion(R)
    expected = Rotation.from_matrix(R).as_quat(canonical=True)
    # The sign is fixed by w >= 0; at w = 0 either sign is the same rotation.
    expected = np.where(expected[:, 3:] < 0, -expected, expected)
    same = np.minimum(np.abs(back - expected).max(1), np.abs(back + expected).max(1))
    assert same.max() < 1e-14
    assert np.all(back[:, 3] >= 0)
    assert back.shape == (500, 4) and matrix_to_quaternion(R[3]).shape == (4,)
    with pytest.raises(InvalidInput):
        matrix_to_quaternion(np.eye(4))
    with pytest.raises(InvalidInput):
        quaternion_to_matrix([1.0, 0.0, 0.0])


def test_wrap_angle_floats_and_arrays():
    a = np.array([-3 * np.pi, -np.pi, -0.5, 0.0, np.pi, 2.5 * np.pi, 7.0])
    w = wrap_angle(a)
    assert np.all((w >= -np.pi) & (w < np.pi))
    # Wrapping subtracts whole turns only: the remainder is exact to a few ulps of 2 pi.
    turns = (a - w) / (2 * np.pi)
    np.testing.assert_allclose(turns, np.round(turns), atol=1e-15)
    assert wrap_angle(np.pi) == -np.pi and isinstance(wrap_angle(1.0), float)
    assert -wrap_angle(-np.pi) == np.pi  # (-pi, pi] as the arm's joints take it
    assert [wrap_angle(float(x)) for x in a] == w.tolist()
