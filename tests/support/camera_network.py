"""A synthetic three-camera network over a home's floor and a robot's drives under it, for the
network calibration's tests: the cameras' truth (K, DIST, `network`), the robot's slip (SLIP)
and its odometry prior drawn from the model's own covariance (`drive`, `segment_cov`),
Zhang-like intrinsics priors (`priors`), the projections of a marker (`observe`) or of it and
a mast's marker (`observe_two`), and the calibrated cameras' errors against the truth
(`camera_errors`)."""

from __future__ import annotations

import numpy as np

from core.calibration.network import IntrinsicsPrior, OdometryPrior, SlipModel
from core.geometry.rotations import matrix_to_rotvec
from core.localization import NetworkCamera

K = np.array([[330.0, 0.0, 320.0], [0.0, 330.0, 240.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.28, 0.07, 0.0005, -0.0004, -0.002])
# The marker's height above the floor (m).
H = 0.36
NAMES = ["a", "b", "c"]
# A Zhang calibration's typical uncertainty (the twin's shown chessboard gives ~0.3 px on the
# focal lengths, ~0.2 px on the principal point).
PRIOR_STD = np.array([0.35, 0.35, 0.25, 0.25, 4e-4, 6e-4, 4e-5, 4e-5, 3e-4])
PRIOR_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
# The default robot's slip (core/sim/data/default_home.yaml).
SLIP = SlipModel(0.01, 0.005, 0.01, 0.01)
# A second marker on a mast, above and behind the first (the default robot's mast marker).
MAST_H, MAST_OFFSET = 1.2, (-0.17, 0.0)


def network() -> list[NetworkCamera]:
    """Return the three ceiling cameras a, b, c (2.8 m up, 640 x 480) looking over the floor."""
    return [
        NetworkCamera.looking_at(K, DIST, [0.3, 0.3, 2.8], [2.3, 2.0, 0.0], (640, 480), "a"),
        NetworkCamera.looking_at(K, DIST, [4.2, 3.7, 2.8], [2.0, 1.8, 0.0], (640, 480), "b"),
        NetworkCamera.looking_at(K, DIST, [4.2, 0.2, 2.8], [2.2, 2.0, 0.0], (640, 480), "c"),
    ]


def segment_cov(inc: np.ndarray) -> np.ndarray:
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


def drive(seed: int, M: int = 40, line: bool = False):
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
    cov = segment_cov(inc)
    noise = np.einsum("mij,mj->mi", np.linalg.cholesky(cov), rng.standard_normal((M, 3)))
    return P, OdometryPrior(start, inc - noise, cov)


def priors(rng: np.random.Generator) -> list[IntrinsicsPrior]:
    """Return each camera's intrinsics prior: the truth plus an error drawn from PRIOR_STD."""
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


def observe(cams: list[NetworkCamera], P: np.ndarray, sigma: float, rng: np.random.Generator):
    """Return pixels (C, M, 2) of the marker at height H over the poses P, with N(0, sigma^2)
    noise, and whether each camera sees it (C, M)."""
    X = np.column_stack([P[:, :2], np.full(len(P), H)])
    vis = np.stack([c.in_view(X) for c in cams])
    px = np.stack([c.project(X) for c in cams])
    return px + sigma * rng.standard_normal(px.shape), vis


def observe_two(cams: list[NetworkCamera], P: np.ndarray, sigma: float, rng: np.random.Generator):
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


def camera_errors(net, cams):
    """Return each calibrated camera's errors against its truth (C, 3): focal length (%),
    centre (m) and orientation (deg)."""
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
