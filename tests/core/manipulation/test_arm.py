"""The arm: forward kinematics, the geometric Jacobian, closed-form and numerical IK."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInput
from core.manipulation import DHArm, default_arm, pose_error
from tests.support.kinematics import pose_jacobian_by_differences

ARM = default_arm()
LO, HI = ARM.limits[:, 0], ARM.limits[:, 1]


def _dh(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """Rz(theta) Tz(d) Tx(a) Rx(alpha), built as four elementary matrices (independent of the
    module's expanded form)."""
    c, s = np.cos(theta), np.sin(theta)
    rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    tz = np.eye(4)
    tz[2, 3] = d
    tx = np.eye(4)
    tx[0, 3] = a
    ca, sa = np.cos(alpha), np.sin(alpha)
    rx = np.array([[1, 0, 0, 0], [0, ca, -sa, 0], [0, sa, ca, 0], [0, 0, 0, 1.0]])
    return rz @ tz @ tx @ rx


def test_fk_matches_elementary_dh_product_and_a_known_pose() -> None:
    rng = np.random.default_rng(0)
    qs = rng.uniform(LO, HI, (20, 6))
    batch = ARM.fk(qs)
    for q, T in zip(qs, batch, strict=True):
        ref = np.eye(4)
        for i in range(6):
            ref = ref @ _dh(q[i], ARM.d[i], ARM.a[i], ARM.alpha[i])
        np.testing.assert_allclose(T, ref @ ARM.tool, atol=1e-14)
    # At q = 0 the Puma's flange is at (a2 + a3, -d3, d4) (Corke, RVC tab. 7.1 geometry), and
    # the 0.12 m tool continues along the flange's z axis, which points up there.
    T0 = ARM.fk(np.zeros(6))
    np.testing.assert_allclose(T0[:3, 3], [0.4318 + 0.0203, -0.15005, 0.4318 + 0.12], atol=1e-12)


def test_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(1)
    h = 1e-6
    for q in rng.uniform(LO, HI, (5, 6)):
        J = ARM.jacobian(q)
        Jn = pose_jacobian_by_differences(ARM.fk, q, h)
        # Central differences: truncation O(h^2) ~ 1e-12, rounding ~1e-16 / h ~ 1e-10.
        np.testing.assert_allclose(J, Jn, atol=1e-8)
        # The scalar path the numerical IK uses agrees with the batched one.
        np.testing.assert_allclose(ARM._kinematics_one(q)[2], J, atol=1e-14)


def test_analytic_ik_round_trip_every_branch() -> None:
    rng = np.random.default_rng(2)
    counts = []
    for q in rng.uniform(LO, HI, (150, 6)):
        if abs(np.sin(q[4])) < 1e-3:
            continue  # at the wrist singularity only q4 + q6 is determined
        T = ARM.fk(q)
        sols = ARM.ik_analytic(T)
        counts.append(len(sols))
        # The configuration that made T is among the branches.
        assert min(np.max(np.abs(s - q)) for s in sols) < 1e-9
        for s in sols:
            assert ARM.within_limits(s)
            dp, dr = pose_error(ARM.fk(s), T)
            # Closed form: atan2/acos of exact values, errors at rounding level.
            assert dp < 1e-12 and dr < 1e-12
    # Eight branches at most, times the 2 pi shifts of q6 (range 532 degrees).
    assert max(counts) <= 16 and min(counts) >= 1


def test_analytic_ik_unreachable_and_wrong_geometry() -> None:
    far = np.eye(4)
    far[:3, 3] = [2.0, 0.0, 0.0]
    assert ARM.ik_analytic(far) == []
    other = DHArm("planar", np.full(6, 0.1), np.zeros(6), np.zeros(6), np.zeros(6), ARM.limits)
    with pytest.raises(InvalidInput, match="closed-form"):
        other.ik_analytic(np.eye(4))
    with pytest.raises(InvalidInput, match="rigid"):
        ARM.ik_analytic(np.diag([2.0, 1.0, 1.0, 1.0]))


def test_numerical_ik_success_rate_and_true_error() -> None:
    rng = np.random.default_rng(3)
    targets = ARM.fk(rng.uniform(LO, HI, (200, 6)))
    results = [ARM.ik(T) for T in targets]
    ok = [r.success for r in results]
    # Spec 05: >= 99.9 % on 1000 poses; on 200 that is every one.
    assert all(ok)
    for r, T in zip(results, targets, strict=True):
        dp, dr = pose_error(ARM.fk(r.q), T)
        assert dp <= 1e-9 and dr <= 1e-9
        assert r.position_error == pytest.approx(dp, abs=1e-15)
        assert ARM.within_limits(r.q)


def test_numerical_ik_from_q0_and_unreachable() -> None:
    q = np.array([0.3, 1.0, -2.5, 0.4, 0.8, -0.2])
    r = ARM.ik(ARM.fk(q), q0=q + 0.05)
    # From a nearby start LM converges to the nearby solution, not another branch.
    assert r.success and np.max(np.abs(r.q - q)) < 1e-8
    far = np.eye(4)
    far[:3, 3] = [2.0, 0.0, 0.0]
    r = ARM.ik(far, max_iterations=100)
    assert not r.success and r.position_error > 0.5
