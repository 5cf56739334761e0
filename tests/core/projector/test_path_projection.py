"""Path projection: the joint trajectory draws the path within the joint limits."""

from __future__ import annotations

import numpy as np
import pytest

from core.projector import PanTiltProjector, UnreachablePoint, fillet_path, project_path


def _projector() -> PanTiltProjector:
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [2.25, 3.0, 2.75]
    return PanTiltProjector(
        T, tilt_limits=(0.0, 1.35), max_rate=(1.0, 1.0), max_acceleration=(2.0, 2.0)
    )


PATH = np.array([[1.6, 1.2], [3.5, 1.2], [3.5, 4.3], [0.7, 4.3], [0.7, 3.3]])


def _seg_distance(P: np.ndarray, poly: np.ndarray) -> np.ndarray:
    a, b = poly[:-1], poly[1:]
    d = b - a
    s = np.clip(np.einsum("nkj,kj->nk", P[:, None] - a, d) / np.sum(d * d, 1), 0, 1)
    foot = a + s[..., None] * d
    return np.min(np.linalg.norm(P[:, None] - foot, axis=2), axis=1)


@pytest.mark.parametrize("corner_radius", [0.0, 0.3])
def test_trajectory_draws_the_path_within_limits(corner_radius: float) -> None:
    proj = _projector()
    traj = project_path(proj, PATH, 0.3, spot_acceleration=0.5, corner_radius=corner_radius)
    # The spot the joints really produce stays on the (filleted) path: the joint angles are
    # interpolated linearly between 5 mm samples, a chord error far below 0.1 mm.
    drawn = proj.spot(traj.q)
    target = fillet_path(PATH, corner_radius) if corner_radius else PATH
    assert np.max(_seg_distance(drawn, target)) < 1e-4
    np.testing.assert_allclose(drawn[[0, -1]], PATH[[0, -1]], atol=1e-9)
    # Rates and accelerations measured on the output by finite differences: the limits hold
    # up to the discretisation of the phase-plane integration (a few percent).
    qd = np.gradient(traj.q, traj.t, axis=0)
    qdd = np.gradient(qd, traj.t, axis=0)
    assert np.all(np.max(np.abs(qd), 0) <= 1.02 * np.array(proj.max_rate))
    assert np.all(np.max(np.abs(qdd), 0) <= 1.1 * np.array(proj.max_acceleration))
    speed = np.linalg.norm(np.diff(drawn, axis=0), axis=1) / np.diff(traj.t)
    assert speed.max() <= 0.3 * 1.01
    # Cruising at the asked speed somewhere: the law is not needlessly slow.
    assert speed.max() >= 0.3 * 0.99
    # The fillets are sampled more finely here than in `target`: chords differ by < 1e-5.
    assert abs(traj.length - np.sum(np.linalg.norm(np.diff(target, axis=0), axis=1))) < 1e-4


def test_corners_stop_the_spot_and_fillets_do_not() -> None:
    proj = _projector()
    sharp = project_path(proj, PATH, 0.3)
    round_ = project_path(proj, PATH, 0.3, corner_radius=0.3)
    # Braking at 0.5 m/s^2 the spot is at most sqrt(2 * 0.5 * 0.02) = 0.14 m/s within 2 cm of
    # the corner, and at rest on it.
    at_corner = np.linalg.norm(sharp.spot - PATH[1], axis=1) < 0.02
    assert np.min(np.linalg.norm(sharp.spot_velocity[at_corner], axis=1)) < 0.03
    assert np.max(np.linalg.norm(sharp.spot_velocity[at_corner], axis=1)) < 0.15
    # Through a 0.3 m fillet the lateral bound allows sqrt(0.5 * 0.3) = 0.39 m/s > 0.3.
    near = np.linalg.norm(round_.spot - PATH[1], axis=1) < 0.2
    assert np.min(np.linalg.norm(round_.spot_velocity[near], axis=1)) > 0.25
    assert round_.duration < sharp.duration


def test_a_path_winding_around_the_foot_past_the_pan_limits_is_refused() -> None:
    loop = np.array([[1.0, 1.5], [3.5, 1.5], [3.5, 4.5], [1.0, 4.5], [1.0, 1.6]])
    with pytest.raises(UnreachablePoint, match="pan past its limits"):
        project_path(_projector(), loop, 0.3)
