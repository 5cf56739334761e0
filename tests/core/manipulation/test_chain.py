"""The whole chain world -> base -> arm -> end effector -> camera."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.poses import planar_pose
from core.manipulation import Unreachable, default_manipulator, pose_error
from tests.support.kinematics import pose_jacobian_by_differences

MM = default_manipulator()


def test_chain_fk_composes_base_mount_arm_and_camera() -> None:
    x = np.concatenate([[1.0, 2.0, 0.7], MM.arm.home])
    T = MM.fk(x)
    ref = planar_pose(x[:3]) @ MM.T_base_arm @ MM.arm.fk(x[3:])
    np.testing.assert_allclose(T, ref, atol=1e-15)
    np.testing.assert_allclose(MM.camera_pose(x), ref @ MM.T_ee_camera, atol=1e-15)
    # Batched: one call for many configurations.
    xs = np.stack([x, x + 0.1])
    assert MM.fk(xs).shape == (2, 4, 4)


def test_chain_jacobian_matches_finite_differences() -> None:
    x = np.concatenate([[1.0, -0.5, 2.0], MM.arm.home + 0.2])
    J = MM.jacobian(x)
    h = 1e-6
    Jn = pose_jacobian_by_differences(MM.fk, x, h)
    # Central differences, h = 1e-6: error ~1e-10.
    np.testing.assert_allclose(J, Jn, atol=1e-8)
    np.testing.assert_allclose(MM._kinematics_one(x)[2], J, atol=1e-14)


def test_whole_chain_ik_reaches_and_moves_the_base_little() -> None:
    rng = np.random.default_rng(4)
    x0 = np.concatenate([[1.0, 2.0, 0.3], MM.arm.home])
    ok = 0
    travel, travel_free = [], []
    for _ in range(20):
        xt = np.concatenate([x0[:3] + rng.normal(0, 0.2, 3), rng.uniform(*MM.arm.limits.T)])
        T = MM.fk(xt)
        r = MM.ik(T, x0)
        ok += r.success
        if r.success:
            assert max(pose_error(MM.fk(r.q), T)) <= 1e-9
            assert MM.arm.within_limits(r.q[3:])
            travel.append(np.linalg.norm(r.q[:2] - x0[:2]))
            free = MM.ik(T, x0, base_weight=1e-3)
            if free.success:
                travel_free.append(np.linalg.norm(free.q[:2] - x0[:2]))
    # Targets drawn from configurations whose base moved 0.2 m (sd): nearly all reachable.
    assert ok >= 19
    # The base weight keeps the base near its start: less travel than with the weight off.
    assert np.median(travel) < np.median(travel_free)


def test_base_placement_reaches_a_table_top_grasp() -> None:
    # A top-down grasp 0.8 m above the floor (a table), gripper z pointing down.
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [3.0, 2.0, 0.8]
    p = MM.place_base(T, np.array([1.0, 1.0, 0.0]))
    assert MM.arm.within_limits(p.q)
    dp, dr = pose_error(MM.fk(p.x), T)
    assert dp < 1e-12 and dr < 1e-12
    assert p.travel == pytest.approx(np.linalg.norm(p.base[:2] - [1.0, 1.0]))
    up = T.copy()
    up[2, 3] = 3.0  # far above the arm's reach from any base pose
    with pytest.raises(Unreachable):
        MM.place_base(up, np.array([1.0, 1.0, 0.0]))
