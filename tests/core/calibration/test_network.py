"""Network calibration: the marker kind (intrinsics priors, odometry prior, joint refinement,
Cramer-Rao bound) on synthetic projections of known cameras, the odometry prior against the
twin's simulated base, and the board kind."""

from __future__ import annotations

import numpy as np
import pytest

from core.calibration.network import (
    IntrinsicsPrior,
    OdometryPrior,
    SlipModel,
    calibrate_network_marker,
    compose_increments,
    floor_gauge_projector,
    increment_jacobian,
    marker_network_bound,
    odometry_prior,
)
from core.calibration.network._marker_image import disc_centre_offset, disc_image_area
from core.errors import InvalidInput
from core.geometry.rotations import matrix_to_rotvec, rotvec_to_matrix
from core.localization import NetworkCamera

K = np.array([[330.0, 0.0, 320.0], [0.0, 330.0, 240.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.28, 0.07, 0.0005, -0.0004, -0.002])
H = 0.36
NAMES = ["a", "b", "c"]
# A Zhang calibration's typical uncertainty (the twin's shown chessboard gives ~0.3 px on the
# focal lengths, ~0.2 px on the principal point).
PRIOR_STD = np.array([0.35, 0.35, 0.25, 0.25, 4e-4, 6e-4, 4e-5, 4e-5, 3e-4])
PRIOR_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
# The default robot's slip (core/sim/data/default_home.yaml).
SLIP = SlipModel(0.01, 0.005, 0.01, 0.01)
BOARD_TILT = 0.5


def _network() -> list[NetworkCamera]:
    return [
        NetworkCamera.looking_at(K, DIST, [0.3, 0.3, 2.8], [2.3, 2.0, 0.0], (640, 480), "a"),
        NetworkCamera.looking_at(K, DIST, [4.2, 3.7, 2.8], [2.0, 1.8, 0.0], (640, 480), "b"),
        NetworkCamera.looking_at(K, DIST, [4.2, 0.2, 2.8], [2.2, 2.0, 0.0], (640, 480), "c"),
    ]


def _segment_cov(inc: np.ndarray) -> np.ndarray:
    """The increments' covariance as odometry_prior gives it for straight moves of these
    lengths after a turn on the spot (independent reference: the same model integrated in
    closed form for one straight leg: along a^2 L, lateral b^2 L + c^2 L^3 / 3 (+ the turn's
    heading noise d^2 |turn| L^2), heading c^2 L + d^2 |turn|)."""
    L = np.linalg.norm(inc[:, :2], axis=1)
    turn = np.abs(np.arctan2(inc[:, 1], inc[:, 0]))
    a, b, c, d = 0.01, 0.005, 0.01, 0.01
    cov = np.zeros((len(inc), 3, 3))
    h0 = d * d * turn
    lat = b * b * L + c * c * L**3 / 3 + h0 * L * L
    th = c * c * L + h0
    cross = c * c * L * L / 2 + h0 * L
    # Rotate the leg's (along, lateral) into the previous stop's frame.
    ca, sa = np.cos(np.arctan2(inc[:, 1], inc[:, 0])), np.sin(np.arctan2(inc[:, 1], inc[:, 0]))
    R = np.zeros((len(inc), 2, 2))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1] = ca, -sa, sa, ca
    C2 = np.zeros((len(inc), 2, 2))
    C2[:, 0, 0] = a * a * L
    C2[:, 1, 1] = lat
    cov[:, :2, :2] = R @ C2 @ np.swapaxes(R, 1, 2)
    cov[:, :2, 2] = (R @ np.stack([np.zeros(len(inc)), cross], 1)[..., None])[..., 0]
    cov[:, 2, :2] = cov[:, :2, 2]
    cov[:, 2, 2] = th
    return cov + 1e-12 * np.eye(3)


def _drive(seed: int, M: int = 40, line: bool = False):
    """Return true poses (M, 3) of a drive over the cameras' floor (along y = 2 with `line`)
    and an OdometryPrior whose increments are the true ones plus noise drawn from their
    covariance."""
    rng = np.random.default_rng(seed)
    xy = np.column_stack([rng.uniform(0.6, 3.8, M), rng.uniform(0.6, 3.4, M)])
    if line:
        xy[:, 1] = 2.0
    start = np.array([1.0, 1.2, 0.0])
    prev = np.vstack([start[:2], xy[:-1]])
    yaw = np.arctan2(xy[:, 1] - prev[:, 1], xy[:, 0] - prev[:, 0])
    P = np.column_stack([xy, yaw])
    before = np.vstack([start, P[:-1]])
    rel = P[:, :2] - before[:, :2]
    c, s = np.cos(before[:, 2]), np.sin(before[:, 2])
    inc = np.column_stack(
        [c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], P[:, 2] - before[:, 2]]
    )
    inc[:, 2] = (inc[:, 2] + np.pi) % (2 * np.pi) - np.pi
    cov = _segment_cov(inc)
    noise = np.einsum("mij,mj->mi", np.linalg.cholesky(cov), rng.standard_normal((M, 3)))
    return P, OdometryPrior(start, inc - noise, cov)


def _priors(rng: np.random.Generator) -> list[IntrinsicsPrior]:
    out = []
    for _ in NAMES:
        e = PRIOR_STD * rng.standard_normal(9)
        Kp = K.copy()
        Kp[0, 0] += e[0]
        Kp[1, 1] += e[1]
        Kp[0, 2] += e[2]
        Kp[1, 2] += e[3]
        out.append(IntrinsicsPrior(Kp, DIST + e[4:], PRIOR_NAMES, np.diag(PRIOR_STD**2)))
    return out


def _observe(cams: list[NetworkCamera], P: np.ndarray, sigma: float, rng: np.random.Generator):
    X = np.column_stack([P[:, :2], np.full(len(P), H)])
    vis = np.stack([c.in_view(X) for c in cams])
    px = np.stack([c.project(X) for c in cams])
    return px + sigma * rng.standard_normal(px.shape), vis


def _errors(net, cams):
    out = []
    for cal, true in zip(net.cameras, cams, strict=True):
        out.append(
            (
                100 * (cal.focal - 330.0) / 330.0,
                np.linalg.norm(cal.position - true.center),
                np.degrees(np.linalg.norm(matrix_to_rotvec(cal.R @ true.R.T))),
            )
        )
    return np.array(out)


def test_compose_and_its_jacobian_agree_with_finite_differences() -> None:
    _, odo = _drive(1, M=6)
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
    ref = _segment_cov(np.array([[0.0, 1.0, np.pi / 2]]))[0]
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


def test_marker_calibration_reaches_its_cramer_rao_bound() -> None:
    # Monte Carlo over 10 drives (0.5 px noise, the default robot's slip, Zhang-like intrinsic
    # priors): the RMS position and orientation errors over 10 x 3 cameras against the RMS of
    # the bound. An RMS over 30 three-dimensional errors has a sampling error of about
    # 1 / sqrt(2 * 90) ~ 7.5 % (more with correlated cameras); [0.6, 1.5] is wide enough for
    # that and fails an estimator off by half or a covariance off by 2.
    cams = _network()
    e2, b2 = [], []
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        P, odo = _drive(seed)
        pri = _priors(rng)
        px, vis = _observe(cams, P, 0.5, rng)
        net = calibrate_network_marker(NAMES, pri, px, vis, odo, H, pixel_sigma=0.5)
        assert not net.rejected
        bound = marker_network_bound(
            NAMES,
            pri,
            [K] * 3,
            [DIST] * 3,
            [c.R for c in cams],
            [c.t for c in cams],
            P,
            vis,
            odo,
            H,
            pixel_sigma=0.5,
        )
        err = _errors(net, cams)
        e2.append(err[:, 1:] ** 2)
        b2.append(np.array([[b.position_m**2, b.rotation_deg**2] for b in bound]))
        # The residual variance the covariances are scaled by is about 1 (unit noise).
        assert abs(net.residual_variance - 1) < 0.35
        assert 0.5 < net.rms_whitened / 0.7 < 1.5  # about sqrt(1 - d / N) of unit noise
    ratio = np.sqrt(np.mean(np.array(e2), axis=(0, 1)) / np.mean(np.array(b2), axis=(0, 1)))
    assert np.all((ratio > 0.6) & (ratio < 1.5)), ratio


# A second marker on a mast, above and behind the first (the default robot's mast marker).
MAST_H, MAST_OFFSET = 1.2, (-0.17, 0.0)


def _observe_two(cams: list[NetworkCamera], P: np.ndarray, sigma: float, rng: np.random.Generator):
    """Return pixels (C, M, 2, 2) and visibility (C, M, 2) of the top and mast markers."""
    c, s = np.cos(P[:, 2]), np.sin(P[:, 2])
    ox, oy = MAST_OFFSET
    X2 = np.column_stack([P[:, 0] + c * ox - s * oy, P[:, 1] + s * ox + c * oy])
    pts = [
        np.column_stack([P[:, :2], np.full(len(P), H)]),
        np.column_stack([X2, np.full(len(P), MAST_H)]),
    ]
    vis = np.stack([np.stack([cm.in_view(X) for X in pts], axis=-1) for cm in cams])
    px = np.stack([np.stack([cm.project(X) for X in pts], axis=1) for cm in cams])
    return px + sigma * rng.standard_normal(px.shape), vis


def test_two_markers_reach_their_bound_and_fix_the_tilt() -> None:
    # The same Monte Carlo as above with the mast marker too: the errors agree with the
    # two-marker bound. And where each stop is seen by one camera only (a room with its own
    # camera), that bound is far below one marker's in orientation: the image of a marker
    # above another gives each camera its tilt at every stop, where one marker gives it only
    # through the odometry between stops.
    cams = _network()
    heights, offsets = [H, MAST_H], [(0.0, 0.0), MAST_OFFSET]
    e2, b2, one2 = [], [], []
    for seed in range(10):
        rng = np.random.default_rng(200 + seed)
        P, odo = _drive(seed)
        pri = _priors(rng)
        px, vis = _observe_two(cams, P, 0.5, rng)
        net = calibrate_network_marker(
            NAMES, pri, px, vis, odo, heights, offset=offsets, pixel_sigma=0.5
        )
        assert not net.rejected
        truth = ([K] * 3, [DIST] * 3, [c.R for c in cams], [c.t for c in cams], P)
        bound = marker_network_bound(
            NAMES, pri, *truth, vis, odo, heights, offset=offsets, pixel_sigma=0.5
        )
        alone = np.zeros_like(vis)  # each stop kept by one of the cameras that see it
        for j in range(len(P)):
            seeing = np.flatnonzero(vis[:, j].any(axis=1))
            if seeing.size:
                k = seeing[j % seeing.size]
                alone[k, j] = vis[k, j]
        one = marker_network_bound(NAMES, pri, *truth, alone[..., 0], odo, H, pixel_sigma=0.5)
        two = marker_network_bound(
            NAMES, pri, *truth, alone, odo, heights, offset=offsets, pixel_sigma=0.5
        )
        err = _errors(net, cams)
        e2.append(err[:, 1:] ** 2)
        b2.append(np.array([[b.position_m**2, b.rotation_deg**2] for b in bound]))
        one2.append(
            np.array(
                [
                    [a.aligned_rotation_deg**2, b.aligned_rotation_deg**2]
                    for a, b in zip(one, two, strict=True)
                ]
            )
        )
        assert abs(net.residual_variance - 1) < 0.35
        for cal in net.cameras:  # stops, not detections; residuals per detection
            k = NAMES.index(cal.name)
            assert cal.poses_seen == vis[k].any(axis=1).sum() and cal.detections == vis[k].sum()
            assert len(cal.pose_index) == len(cal.residuals) == vis[k].sum() - cal.outliers
    ratio = np.sqrt(np.mean(np.array(e2), axis=(0, 1)) / np.mean(np.array(b2), axis=(0, 1)))
    assert np.all((ratio > 0.6) & (ratio < 1.5)), ratio
    one_rot, two_rot = np.sqrt(np.mean(np.array(one2), axis=(0, 1)))
    assert one_rot > 2.0 * two_rot, (one_rot, two_rot)  # measured 0.67 against 0.24 deg


def test_marker_layouts_are_checked() -> None:
    cams = _network()
    rng = np.random.default_rng(1)
    P, odo = _drive(1)
    px, vis = _observe_two(cams, P, 0.5, rng)
    pri = _priors(rng)
    with pytest.raises(InvalidInput, match="offset"):
        calibrate_network_marker(NAMES, pri, px, vis, odo, [H, MAST_H], offset=(0.0, 0.0, 1.0))
    with pytest.raises(InvalidInput, match="pixels"):  # two markers' pixels, one height
        calibrate_network_marker(NAMES, pri, px, vis, odo, H)
    with pytest.raises(InvalidInput, match="finite"):
        calibrate_network_marker(
            NAMES, pri, px, vis, odo, [H, np.nan], offset=[(0, 0), MAST_OFFSET]
        )


def test_per_pose_residuals_and_labelled_rms() -> None:
    cams = _network()
    rng = np.random.default_rng(5)
    P, odo = _drive(5)
    px, vis = _observe(cams, P, 0.5, rng)
    net = calibrate_network_marker(NAMES, _priors(rng), px, vis, odo, H, pixel_sigma=0.5)
    for cal in net.cameras:
        assert len(cal.pose_index) == len(cal.residuals) == vis[NAMES.index(cal.name)].sum()
        assert cal.parameter_names[:4] == ("fx", "fy", "cx", "cy")
        assert cal.covariance.shape == (15, 15)
    # The overall RMS in pixels sits among the cameras' own (it is their pooled RMS).
    rms = [c.rms for c in net.cameras]
    assert min(rms) <= net.rms_px <= max(rms)
    per_pose = net.pose_rms_px
    assert per_pose.shape == (40,) and np.nanmax(per_pose) < 5 * 0.5
    assert net.targets.shape == (40, 3) and net.target_cov.shape == (40, 3, 3)
    # The refined poses are closer to the truth than the odometry's.
    drift = np.linalg.norm(odo.poses[:, :2] - P[:, :2], axis=1)
    fixed = np.linalg.norm(net.targets[:, :2] - P[:, :2], axis=1)
    assert np.sqrt(np.mean(fixed**2)) < 0.5 * np.sqrt(np.mean(drift**2))


def test_cameras_with_too_few_or_collinear_poses_are_reported_by_name() -> None:
    cams = _network()
    rng = np.random.default_rng(4)
    P, odo = _drive(4)
    px, vis = _observe(cams, P, 0.5, rng)
    vis[1, np.flatnonzero(vis[1])[4:]] = False  # b sees 4 stops
    net = calibrate_network_marker(NAMES, _priors(rng), px, vis, odo, H, pixel_sigma=0.5)
    reasons = {r.name: r.reason for r in net.rejected}
    assert "too few poses: saw 4" in reasons["b"]
    assert {c.name for c in net.cameras} == {"a", "c"}
    # Collinear: every stop on one line.
    P2, odo2 = _drive(4, line=True)
    px2, vis2 = _observe(cams, P2, 0.5, rng)
    net2 = calibrate_network_marker(NAMES, _priors(rng), px2, vis2, odo2, H, pixel_sigma=0.5)
    assert all("collinear" in r.reason for r in net2.rejected) and net2.rejected
    with pytest.raises(InvalidInput):
        net2.camera(net2.rejected[0].name)


def test_marker_inputs_are_checked() -> None:
    cams = _network()
    rng = np.random.default_rng(0)
    P, odo = _drive(0)
    px, vis = _observe(cams, P, 0.5, rng)
    pri = _priors(rng)
    with pytest.raises(InvalidInput, match="pixels"):
        calibrate_network_marker(NAMES, pri, px[:, :5], vis, odo, H)
    with pytest.raises(InvalidInput, match="prior"):
        calibrate_network_marker(NAMES, pri[:2], px, vis, odo, H)
    bad = px.copy()
    bad[vis] = np.nan
    with pytest.raises(InvalidInput, match="finite"):
        calibrate_network_marker(NAMES, pri, bad, vis, odo, H)
    with pytest.raises(InvalidInput, match="stops"):
        odometry_prior(np.zeros((5, 3)), [0, 3], SLIP)


def test_disc_centre_offset_without_distortion_is_the_renderers_ellipse_centre() -> None:
    # Independent reference: core.sim.render's conic centre of the disc's image (H & Z eq.
    # 2.13), exact without distortion. The inscribed 48-gon's centroid differs by O(n^-2) of
    # the perspective offset: measured 8e-4 px, bound 3e-3 px.
    from core.sim.render import CameraModel, _disc_image_centre

    cam = _network()[1]
    none = np.zeros(5)
    model = CameraModel("b", 640, 480, K, none, cam.R.T, cam.center, 15.0)
    X = np.array([[1.0, 1.0, H], [3.5, 2.5, H], [0.5, 3.0, H]])
    off = disc_centre_offset(X, matrix_to_rotvec(cam.R), cam.t, K, none, 0.08)
    want = np.array([_disc_image_centre(model, x, 0.08) for x in X]) - model.project(X)
    np.testing.assert_allclose(off, want, atol=3e-3)
    assert np.all(np.linalg.norm(off, axis=1) > 0.02)  # the effect is there to model


def test_disc_centre_offset_is_the_centroid_of_the_pixels_the_disc_covers() -> None:
    # Independent reference, as for the area below: the image plane sampled at 1/8 px, each
    # sample undistorted by OpenCV, its ray met with the disc's plane, and the centroid taken
    # of those within the radius (what a detector's soft centroid measures). With k1 = -0.28
    # that centroid is up to a quarter of a pixel from the distorted ellipse centre the model
    # used to predict (the renderer's truth) for an 8 cm disc near the image's edge, a
    # magnification of the focal length to the model: it must follow the pixels.
    import cv2

    from core.sim.render import CameraModel, _disc_image_centre

    cam = _network()[1]
    model = CameraModel("b", 640, 480, K, DIST, cam.R.T, cam.center, 15.0)
    rv, r = matrix_to_rotvec(cam.R), 0.08
    # On the axis, off it, and near the image's lower edge, close to the camera.
    X = np.array([[2.0, 1.8, H], [3.6, 0.6, H], [3.8, 3.3, H]])
    off = disc_centre_offset(X, rv, cam.t, K, DIST, r)
    gaps = []
    for x, o in zip(X, off, strict=True):
        c = cam.project(x[None])[0]
        half = 3 * np.sqrt(disc_image_area(x[None], rv, cam.t, K, DIST, r)[0] / np.pi)
        g = np.arange(-half, half, 0.125) + 0.0625
        u, v = np.meshgrid(c[0] + g, c[1] + g)
        uv = np.stack([u.ravel(), v.ravel()], 1)
        n = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, DIST).reshape(-1, 2)
        rays = np.column_stack([n, np.ones(len(n))]) @ cam.R  # world directions
        lam = (H - cam.center[2]) / rays[:, 2]
        hit = cam.center + lam[:, None] * rays
        inside = np.sum((hit[:, :2] - x[:2]) ** 2, axis=1) <= r * r
        centroid = uv[inside].mean(axis=0)
        # Sampling 1/64 px^2 cells over a few hundred px^2: the centroid to ~0.005 px.
        np.testing.assert_allclose(c + o, centroid, atol=0.01)
        gaps.append(np.linalg.norm(centroid - _disc_image_centre(model, x, r)))
    # Measured 0.004, 0.07 and 0.23 px: the distortion's share is there to model.
    assert max(gaps) > 0.15, gaps


def test_disc_image_area_matches_a_count_of_the_pixels_it_covers() -> None:
    # Independent reference: the image plane sampled at 1/8 px, each sample undistorted by
    # OpenCV (cv2.undistortPoints), its ray met with the disc's plane and counted when it
    # falls within the radius. Sampling 1/64 px^2 cells over a ~700 px^2 image: < 0.5 %.
    import cv2

    cam = _network()[1]
    rv, r = matrix_to_rotvec(cam.R), 0.08
    X = np.array([[2.0, 1.8, H], [0.8, 0.9, H]])  # near the image centre, and far off it
    got = disc_image_area(X, rv, cam.t, K, DIST, r)
    for x, area in zip(X, got, strict=True):
        c = cam.project(x[None])[0]
        half = 3 * np.sqrt(area / np.pi)
        g = np.arange(-half, half, 0.125) + 0.0625
        u, v = np.meshgrid(c[0] + g, c[1] + g)
        uv = np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2)
        n = cv2.undistortPoints(uv, K, DIST).reshape(-1, 2)
        rays = np.column_stack([n, np.ones(len(n))]) @ cam.R  # world directions
        lam = (H - cam.center[2]) / rays[:, 2]
        hit = cam.center + lam[:, None] * rays
        inside = np.sum((hit[:, :2] - x[:2]) ** 2, axis=1) <= r * r
        np.testing.assert_allclose(area, inside.sum() / 64.0, rtol=0.005)
    assert got[1] < 0.9 * got[0]  # oblique and far: smaller


def test_a_partly_hidden_marker_is_dropped_by_its_area() -> None:
    # The detector's kind of data: the disc's ellipse centres with 0.05 px noise and their
    # areas with 1 px noise. One detection is of a marker half hidden by an edge: its centre
    # 2.5 px off, its area 40 % of the disc's. Given the areas, the calibration drops that
    # one detection and nothing else: the same answer as if that camera had not seen it.
    cams = _network()
    rng = np.random.default_rng(21)
    P, odo = _drive(21)
    pri = _priors(rng)
    X = np.column_stack([P[:, :2], np.full(len(P), H)])
    r = 0.05
    vis = np.stack([c.in_view(X) for c in cams])
    px = np.stack(
        [c.project(X) + disc_centre_offset(X, matrix_to_rotvec(c.R), c.t, K, DIST, r) for c in cams]
    )
    px += 0.05 * rng.standard_normal(px.shape)
    areas = np.stack([disc_image_area(X, matrix_to_rotvec(c.R), c.t, K, DIST, r) for c in cams])
    areas += rng.standard_normal(areas.shape)
    k, j = 0, int(np.flatnonzero(vis[0])[3])
    px[k, j] += [2.0, 1.5]
    areas[k, j] *= 0.4
    kw = {"radius": r, "pixel_sigma": 0.05}
    net = calibrate_network_marker(NAMES, pri, px, vis, odo, H, areas=areas, **kw)
    assert [c.outliers for c in net.cameras] == [1, 0, 0]
    assert j not in net.cameras[0].pose_index
    unseen = vis.copy()
    unseen[k, j] = False
    ref = calibrate_network_marker(NAMES, pri, px, unseen, odo, H, **kw)
    for a, b in zip(net.cameras, ref.cameras, strict=True):
        np.testing.assert_allclose(a.position, b.position, atol=1e-9)
    # Without the areas only the residuals tell, after the hidden marker has pulled the
    # stop's pose: good detections go with it.
    blind = calibrate_network_marker(NAMES, pri, px, vis, odo, H, **kw)
    assert sum(c.outliers for c in blind.cameras) > 1
    with pytest.raises(InvalidInput, match="areas"):
        calibrate_network_marker(NAMES, pri, px, vis, odo, H, areas=areas[:, :5], **kw)
    with pytest.raises(InvalidInput, match="hidden_fraction"):
        calibrate_network_marker(NAMES, pri, px, vis, odo, H, hidden_fraction=1.5, **kw)


def test_floor_gauge_projector_removes_a_floor_rigid_motion() -> None:
    cams = _network()
    centres = np.array([c.center for c in cams])
    th, d = 0.01, np.array([0.03, -0.02, 0.0])
    Rz = rotvec_to_matrix([0.0, 0.0, th])
    e = np.concatenate([np.concatenate([Rz @ c + d - c, [0.0, 0.0, th]]) for c in centres])
    # First order: the residue is O(theta^2) of metres-sized lever arms.
    assert np.max(np.abs(floor_gauge_projector(centres) @ e)) < 1e-3
    other = np.zeros(18)
    other[2] = 0.05  # a height error is not a floor motion: it stays
    assert np.linalg.norm(floor_gauge_projector(centres) @ other) > 0.04


def _board() -> tuple[np.ndarray, np.ndarray]:
    """Model points (24, 3) of a 6 x 4 board of 8 cm squares and its mounting T_robot_board:
    tilted forward and up by BOARD_TILT about the robot's y axis, grid centred 0.5 m up."""
    from core.calibration import Chessboard, board_object_points

    P = board_object_points(Chessboard(6, 4), 0.08)
    u = np.array([0.0, 1.0, 0.0])
    v = np.array([np.cos(BOARD_TILT), 0.0, -np.sin(BOARD_TILT)])
    T = np.eye(4)
    T[:3, :3] = np.column_stack([u, v, np.cross(u, v)])
    T[:3, 3] = np.array([0.0, 0.0, 0.5]) - u * 0.2 - v * 0.12
    return P, T


def _board_views(cams: list[NetworkCamera], n: int, sigma: float, seed: int):
    """Return robot poses (n, 3), corners (C, n, 24, 2) with N(0, sigma^2) noise and whether
    each camera sees the whole board's printed face (C, n)."""
    rng = np.random.default_rng(seed)
    P, T_rb = _board()
    poses = np.column_stack(
        [rng.uniform(0.5, 3.8, n), rng.uniform(0.5, 3.5, n), rng.uniform(-np.pi, np.pi, n)]
    )
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    R = np.zeros((n, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    B = P @ T_rb[:3, :3].T + T_rb[:3, 3]  # (24, 3) robot frame
    X = np.einsum("nij,kj->nki", R, B)
    X[..., :2] += poses[:, None, :2]
    face = -(R @ T_rb[:3, 2])  # printed face's normal, (n, 3)
    uv = np.zeros((len(cams), n, len(P), 2))
    vis = np.zeros((len(cams), n), bool)
    for k, cam in enumerate(cams):
        toward = np.einsum("ni,ni->n", face, cam.center - X.mean(1)) > 0
        inside = cam.in_view(X.reshape(-1, 3)).reshape(n, len(P)).all(1)
        vis[k] = toward & inside
        uv[k] = cam.project(X.reshape(-1, 3)).reshape(n, len(P), 2)
    return poses, uv + sigma * rng.standard_normal(uv.shape), vis


def test_board_kind_recovers_intrinsics_distortion_and_poses() -> None:
    from core.calibration.network import calibrate_network_board

    cams = _network()
    P, T_rb = _board()
    poses, uv, vis = _board_views(cams, 160, 0.1, 11)
    # Half the views in the detector's other corner order (a half turn of the grid), and a
    # mirrored order in one view of camera a: the vote must turn the first back, drop the other.
    uv[:, 1::2] = uv[:, 1::2, ::-1]
    j = np.flatnonzero(vis[0])[0]
    uv[0, j] = uv[0, j].reshape(4, 6, 2)[::-1].reshape(24, 2)
    net = calibrate_network_board(
        [c.name for c in cams], [(640, 480)] * 3, uv, vis, P, T_rb, poses, pixel_sigma=0.1
    )
    assert not net.rejected
    for cal, true in zip(net.cameras, cams, strict=True):
        assert cal.poses_seen >= 20, cal.poses_seen
        # 0.1 px noise on >= 20 views of 24 corners: focal to 0.2 %, principal point to 1 px,
        # the centre to 5 mm and the orientation to 0.05 deg (a few standard deviations).
        assert abs(cal.focal / 330.0 - 1) < 2e-3
        assert np.linalg.norm(cal.K[:2, 2] - [320, 240]) < 1.0
        assert np.linalg.norm(cal.position - true.center) < 5e-3
        ang = np.degrees(np.linalg.norm(matrix_to_rotvec(cal.R @ true.R.T)))
        assert ang < 0.05
        # k1, k2 of a strong barrel lens within a few percent; the fit is at the noise.
        np.testing.assert_allclose(cal.dist[:2], DIST[:2], rtol=0.1)
        assert cal.rms < 0.15
        assert cal.parameter_names[:4] == ("fx", "fy", "cx", "cy")
        assert len(cal.std) == len(cal.parameter_names)
    assert net.camera("a").outliers >= 1
    assert net.targets.shape == (160, 3)


def test_board_kind_rejects_a_camera_with_too_few_views_by_name() -> None:
    from core.calibration.network import calibrate_network_board

    cams = _network()
    P, T_rb = _board()
    poses, uv, vis = _board_views(cams, 120, 0.1, 12)
    vis[1, np.flatnonzero(vis[1])[5:]] = False
    net = calibrate_network_board(
        [c.name for c in cams],
        [(640, 480)] * 3,
        uv,
        vis,
        P,
        T_rb,
        poses,
        pose_sigma=(0.002, 0.003),
        min_views=8,
    )
    assert [r.name for r in net.rejected] == ["b"]
    assert "too few board views: saw 5" in net.rejected[0].reason
    assert {c.name for c in net.cameras} == {"a", "c"}
    assert net.target_cov.shape == (120, 3, 3)
    with pytest.raises(InvalidInput, match="too few board views"):
        net.camera("b")


def test_board_kind_checks_its_inputs() -> None:
    from core.calibration.network import calibrate_network_board

    P, T_rb = _board()
    with pytest.raises(InvalidInput):
        calibrate_network_board(
            ["a"],
            [(640, 480)],
            np.zeros((1, 5, 23, 2)),
            np.ones((1, 5), bool),
            P,
            T_rb,
            np.zeros((5, 3)),
        )
    with pytest.raises(InvalidInput, match="distortion"):
        calibrate_network_board(
            ["a"],
            [(640, 480)],
            np.zeros((1, 5, 24, 2)),
            np.ones((1, 5), bool),
            P,
            T_rb,
            np.zeros((5, 3)),
            distortion="fisheye",
        )
