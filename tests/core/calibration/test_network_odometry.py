"""The network calibration's odometry prior: composing a drive's increments and its Jacobian, and
the prior's covariance against the slip model's closed form and the twin's simulated base."""

from __future__ import annotations

import numpy as np

from core.calibration.network import compose_increments, increment_jacobian, odometry_prior
from tests.support.camera_network import SLIP, drive, segment_cov


def test_compose_and_its_jacobian_agree_with_finite_differences() -> None:
    _, odo = drive(1, M=6)
    D = increment_jacobian(odo.start, odo.increments).reshape(18, 18)
    num = np.zeros((18, 18))
    for i in range(18):
        d = np.zeros(18)
        d[i] = 1e-6
        hi = compose_increments(odo.start, odo.increments + d.reshape(6, 3))
        lo = compose_increments(odo.start, odo.increments - d.reshape(6, 3))
        num[:, i] = ((hi - lo) / 2e-6).ravel()
    np.testing.assert_allclose(D, num, atol=1e-7)
    assert np.all(D.reshape(6, 3, 6, 3)[0, :, 1:, :] == 0)  # pose 0 ignores later increments


def test_odometry_prior_is_the_slip_models_covariance() -> None:
    # A straight 1 m leg after a quarter turn, integrated at the twin's 0.05 s steps: the
    # propagated covariance against the closed form of the same model (_segment_cov), which
    # agree to the discretisation (dt 0.05 s at 0.5 m/s: 2.5 cm steps, < 3 %).
    n_turn, n_go = 40, 80
    yaw = np.concatenate([np.linspace(0, np.pi / 2, n_turn + 1), np.full(n_go, np.pi / 2)])
    y = np.concatenate([np.zeros(n_turn + 1), np.linspace(0, 1.0, n_go + 1)[1:]])
    odo = np.column_stack([np.zeros_like(y), y, yaw])
    prior = odometry_prior(odo, [len(odo) - 1], SLIP)
    np.testing.assert_allclose(prior.increments[0], [0.0, 1.0, np.pi / 2], atol=1e-12)
    ref = segment_cov(np.array([[0.0, 1.0, np.pi / 2]]))[0]
    np.testing.assert_allclose(prior.cov[0], ref, rtol=0.03, atol=1e-9)


def test_odometry_prior_against_the_twins_wheel_slip() -> None:
    # Monte Carlo of the twin's base (core.sim.motion.UnicycleBase): the truth-minus-odometry
    # increments over 300 drives have the covariance the prior claims. 300 samples estimate a
    # variance to sqrt(2 / 300) ~ 8 %; 30 % is almost four of those.
    from core.sim import default_scene
    from core.sim.motion import Patrol, UnicycleBase

    robot = default_scene().robot
    assert robot is not None
    stops = np.array([[2.0, 1.5], [2.8, 2.6]])
    errs, cov = [], None
    for seed in range(300):
        base = UnicycleBase.from_robot(robot, rng=seed)
        odo, tru, idx = [base.state.odometry.as_array()], [base.state.pose.as_array()], []
        for goal in stops:
            patrol = Patrol([goal], robot.limits, loop=False)
            for _ in range(400):
                st = base.step(*patrol.command(base.state.odometry))
                odo.append(st.odometry.as_array())
                tru.append(st.pose.as_array())
                if patrol.done and st.v == 0.0 and st.omega == 0.0:
                    break
            idx.append(len(odo) - 1)
        p = odometry_prior(np.array(odo), idx, SLIP)
        t = odometry_prior(np.array(tru), idx, SLIP)
        e = t.increments - p.increments
        e[:, 2] = (e[:, 2] + np.pi) % (2 * np.pi) - np.pi
        errs.append(e)
        cov = p.cov
    E = np.array(errs)
    assert cov is not None
    for j in range(2):
        emp = np.cov(E[:, j].T)
        np.testing.assert_allclose(np.diag(emp), np.diag(cov[j]), rtol=0.3)
