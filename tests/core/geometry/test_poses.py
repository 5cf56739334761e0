import numpy as np

from core.geometry.poses import invert_pose, planar_pose, pose_from_quaternion
from core.geometry.rotations import rotvec_to_matrix


def test_invert_pose_against_the_general_inverse():
    rng = np.random.default_rng(2)
    T = np.tile(np.eye(4), (50, 1, 1))
    T[:, :3, :3] = rotvec_to_matrix(rng.normal(size=(50, 3)))
    T[:, :3, 3] = rng.uniform(-5.0, 5.0, size=(50, 3))
    # The closed form and LU agree to rounding on well-conditioned rigid transforms (|t| <= 9 m).
    np.testing.assert_allclose(invert_pose(T), np.linalg.inv(T), atol=1e-13)
    np.testing.assert_allclose(invert_pose(T[0]) @ T[0], np.eye(4), atol=1e-13)


def test_pose_from_quaternion():
    # 90 degrees about Z (x, y, z, w), not normalised: x goes to y, then the translation.
    T = pose_from_quaternion([1.0, 2.0, 3.0], [0.0, 0.0, 2.0, 2.0])
    np.testing.assert_allclose(T @ [1.0, 0.0, 0.0, 1.0], [1.0, 3.0, 3.0, 1.0], atol=1e-15)
    batch = pose_from_quaternion(np.zeros((3, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)))
    np.testing.assert_array_equal(batch, np.tile(np.eye(4), (3, 1, 1)))


def test_planar_pose_is_a_turn_about_z_then_the_floor_offset():
    rng = np.random.default_rng(3)
    xyt = rng.uniform(-4.0, 4.0, size=(20, 3))
    T = planar_pose(xyt)
    assert T.shape == (20, 4, 4)
    # The independent reference: the rotation vector (0, 0, theta) by Rodrigues' formula.
    np.testing.assert_allclose(
        T[:, :3, :3], rotvec_to_matrix(xyt * [0.0, 0.0, 1.0]), rtol=0.0, atol=1e-15
    )
    np.testing.assert_array_equal(T[:, :3, 3], np.column_stack([xyt[:, :2], np.zeros(20)]))
    np.testing.assert_array_equal(T[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (20, 1)))
    # One pose: a quarter turn at (1, 2) takes the body's x axis to the world's y.
    one = planar_pose((1.0, 2.0, np.pi / 2))
    np.testing.assert_allclose(one @ [1.0, 0.0, 0.0, 1.0], [1.0, 3.0, 0.0, 1.0], atol=1e-15)
