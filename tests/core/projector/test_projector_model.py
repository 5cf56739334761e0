"""The pan-tilt projector: forward/inverse round trip, Jacobian, singularity, typed errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.projector import (
    BeamAboveHorizon,
    BeamMissesFloor,
    PanTiltProjector,
    UnreachablePoint,
)


def _mount(z: float = 2.75) -> np.ndarray:
    # The default home's mount: base z axis pointing down (a half turn about x).
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [2.25, 3.0, z]
    return T


def _with_offsets() -> PanTiltProjector:
    return PanTiltProjector(
        _mount(),
        theta=np.array([0.01, -0.02]),
        d=np.array([0.03, 0.01]),
        a=np.array([0.02, 0.015]),
        alpha=np.array([-math.pi / 2 + 0.003, 0.002]),
        beam_origin=np.array([0.01, 0.0, 0.02]),
        tilt_limits=(0.0, 1.35),
    )


def _joint_samples(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    # Over the whole joint range except the pan singularity (tilt < 0.02 rad: the pan of a
    # spot 5 cm from the foot is still determined, but only to ~1e-9 / 0.05 rad).
    return np.column_stack([rng.uniform(-math.pi, math.pi, n), rng.uniform(0.02, 1.35, n)])


def test_ideal_spot_matches_the_closed_form_direction() -> None:
    proj = PanTiltProjector(_mount(), tilt_limits=(0.0, 1.35))
    q = np.array([[0.3, 0.5], [2.0, 1.2], [-1.0, 0.0]])
    # Base direction (sin t cos p, sin t sin p, cos t), base axes (x, -y, -z) in the world.
    d = np.column_stack(
        [np.sin(q[:, 1]) * np.cos(q[:, 0]), -np.sin(q[:, 1]) * np.sin(q[:, 0]), -np.cos(q[:, 1])]
    )
    expected = np.array([2.25, 3.0]) + 2.75 * d[:, :2] / -d[:, 2:3]
    np.testing.assert_allclose(proj.spot(q), expected, atol=1e-12)


@pytest.mark.parametrize("ideal", [True, False])
def test_forward_inverse_round_trip_is_exact(ideal: bool) -> None:
    proj = PanTiltProjector(_mount(), tilt_limits=(0.0, 1.35)) if ideal else _with_offsets()
    q = _joint_samples(3000, seed=1)
    X = proj.spot(q)
    # Start Newton from a neighbouring configuration (the branch nearest is the true one).
    q_back = proj.aim(X, q + 0.02)
    d = q_back - q
    d[:, 0] = (d[:, 0] + math.pi) % (2 * math.pi) - math.pi  # pan +-pi are one angle
    assert np.max(np.abs(d)) < 1e-9
    assert np.max(np.linalg.norm(proj.spot(q_back) - X, axis=1)) < 1e-9


def test_aim_picks_the_pan_turn_nearest_the_current_angles() -> None:
    proj = PanTiltProjector(_mount(), pan_limits=(-4.0, 4.0), tilt_limits=(0.0, 1.35))
    target = proj.spot([3.0, 0.8])
    np.testing.assert_allclose(proj.aim(target, [3.1, 0.8]), [3.0, 0.8], atol=1e-9)
    np.testing.assert_allclose(proj.aim(target, [-3.0, 0.8]), [3.0 - 2 * math.pi, 0.8], atol=1e-9)


def test_jacobian_matches_central_differences() -> None:
    proj = _with_offsets()
    q = _joint_samples(50, seed=2)
    J = proj.jacobian(q).J
    h = 1e-6
    for j in range(2):
        dq = np.zeros(2)
        dq[j] = h
        fd = (proj.spot(q + dq) - proj.spot(q - dq)) / (2 * h)
        # Central differences are exact to O(h^2 |X'''|) ~ 1e-11 plus rounding 1e-16 / h.
        np.testing.assert_allclose(J[:, :, j], fd, atol=1e-8)


def test_pan_singularity_is_flagged_and_rates_stay_finite() -> None:
    proj = PanTiltProjector(_mount(), tilt_limits=(0.0, 1.35))
    jac = proj.jacobian(np.array([[0.4, 0.0], [0.4, 0.5]]))
    assert jac.singular.tolist() == [True, False]
    qdot = proj.joint_rates([0.4, 0.0], [0.3, 0.0])
    assert np.all(np.isfinite(qdot))
    # Away from it the damped inverse is the exact one (error O(damping^2 / sigma^2)).
    q = np.array([0.4, 0.5])
    v = np.array([0.2, -0.1])
    np.testing.assert_allclose(proj.spot_velocity(q, proj.joint_rates(q, v)), v, atol=1e-6)


def test_beams_that_miss_the_floor_raise_typed_errors() -> None:
    proj = PanTiltProjector(_mount(), tilt_limits=(0.0, 1.35))
    with pytest.raises(BeamAboveHorizon, match="lower the tilt"):
        proj.spot([0.0, math.pi / 2 + 0.1])
    below = PanTiltProjector(_mount(z=-0.5))
    with pytest.raises(BeamMissesFloor, match="behind its origin"):
        below.spot([0.0, 0.3])
    assert np.isnan(proj.spot([[0.0, 2.0]], strict=False)).all()


def test_points_beyond_the_tilt_limit_are_unreachable() -> None:
    proj = PanTiltProjector(_mount(), tilt_limits=(0.0, 1.0))
    far = np.array([2.25 + 2.75 * math.tan(1.1), 3.0])
    with pytest.raises(UnreachablePoint, match="outside the projector's reach"):
        proj.aim(far)
