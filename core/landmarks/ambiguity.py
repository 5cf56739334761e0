"""Poses an image cannot decide between: the two poses of a circle, their probabilities, and
their fusion over views until one view, or several together, decides.

A circle seen in perspective has two poses that project it onto the same ellipse (spec 04
sec. 4). What separates them in one image is the rest of the landmark: the image of the rings'
common centre, the QR symbol's squareness, a mounting prior. Each gives a likelihood per pose;
their product, normalised over the two poses, is each pose's probability given the image
(equal priors). A pose is **decided** when its probability is at least DECIDED_PROBABILITY:
if the likelihoods are those of the measurement noise, a decided pose is then the wrong one at
most 1 - DECIDED_PROBABILITY of the time. Otherwise both poses are kept (`PoseHypothesis`, best
first), and a single Gaussian summary of the two (`covering_covariance`) covers both, so a
consumer that takes one pose and one covariance never gets a good pose's confidence.

Views fuse by `fuse_hypotheses`: every pair of hypotheses of two views (in one frame) is
weighed by their probabilities and their agreement (a Gaussian in the difference of the two
poses, under the sum of their covariances), the pair's pose is their information-weighted
mean, and the weights are renormalised: the wrong poses of two views from different
directions disagree (each is the true pose mirrored about its own line of sight), so the
combined likelihood ratio decides what neither view could.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.rotations import matrix_to_rotvec, nearest_rotation, rotvec_to_matrix

Array = NDArray[np.float64]

# A pose is decided at this probability: 100 to 1 against the other, so at most 1 % of decided
# poses are the wrong one when the likelihoods are the noise's.
DECIDED_PROBABILITY = 0.99
# A pair of hypotheses of two sets agrees when the squared Mahalanobis distance of their poses
# is under this (chi-square, 6 degrees of freedom, 1 - 1e-6): no pair agreeing means another
# landmark, or a moved one.
AGREE_CHI2 = 35.89
# Hypotheses of a fused set below this probability are dropped (they can no longer win against
# a decided one by DECIDED_PROBABILITY within a few views).
DROP_PROBABILITY = 1e-6


@dataclass(frozen=True)
class PoseHypothesis:
    """One pose a landmark may have: T (4, 4) the mark frame in the frame of its container
    (the camera for a detection, the odometry or world frame for a fused track), cov (6, 6)
    of (rotation, translation) as that container states, and its probability given what was
    seen (the hypotheses of one container sum to 1)."""

    T: Array = field(repr=False)
    cov: Array = field(repr=False)
    probability: float

    @property
    def normal(self) -> Array:
        """Return the mark's unit normal (3,) out of its printed face."""
        return self.T[:3, 2]

    @property
    def position(self) -> Array:
        """Return the mark's centre (3,)."""
        return self.T[:3, 3]


def probabilities(log_likelihoods: Array) -> Array:
    """Return the probabilities (n,) of n hypotheses from their log-likelihoods (n,) (equal
    priors): exp(l_i) / sum_j exp(l_j), computed stably; -inf is an impossible hypothesis."""
    ll = np.asarray(log_likelihoods, dtype=np.float64)
    if ll.ndim != 1 or len(ll) == 0 or np.any(np.isnan(ll)) or not np.any(np.isfinite(ll)):
        raise InvalidInput("log-likelihoods must be a non-empty vector with a finite entry")
    w = np.exp(ll - np.max(ll))
    return np.asarray(w / np.sum(w), dtype=np.float64)


def is_decided(hypotheses: tuple[PoseHypothesis, ...]) -> bool:
    """Return whether the first (most probable) hypothesis is decided (module docstring)."""
    return len(hypotheses) <= 1 or hypotheses[0].probability >= DECIDED_PROBABILITY


def covering_covariance(hypotheses: tuple[PoseHypothesis, ...]) -> Array:
    """Return the (6, 6) second moment of the hypotheses' mixture about the first one's pose,
    of (left rotation perturbation, translation): sum_i p_i (C_i + d_i d_i^T), with d_i the
    hypothesis' offset (log(R_i R_0^T), t_i - t_0), p_i their probabilities renormalised over
    those given. The hypotheses' cov must be of the left perturbation. A Gaussian with it
    covers every hypothesis: hypothesis i lies within d_i^T C^-1 d_i <= 1 / p_i of it."""
    if not hypotheses or sum(h.probability for h in hypotheses) <= 0:
        raise InvalidInput("covering_covariance needs a hypothesis of positive probability")
    R0, t0 = hypotheses[0].T[:3, :3], hypotheses[0].T[:3, 3]
    C = np.zeros((6, 6))
    for h in hypotheses:
        d = np.concatenate([matrix_to_rotvec(h.T[:3, :3] @ R0.T), h.T[:3, 3] - t0])
        C += h.probability * (h.cov + np.outer(d, d))
    C /= sum(h.probability for h in hypotheses)  # (of those given, should they not sum to 1)
    return 0.5 * (C + C.T)


def _gaussian_fusion(
    T1: Array, C1: Array, T2: Array, C2: Array
) -> tuple[Array, Array, float, float] | None:
    """Return (fused pose, its covariance, log agreement, squared Mahalanobis distance) of two
    estimates of one pose (cov of (left rotation perturbation, position), in one frame): the
    information-weighted mean on the tangent space at T1 and log N(d; 0, C1 + C2), d the
    second's offset from the first. None when the covariances are singular."""
    d = np.concatenate([matrix_to_rotvec(T2[:3, :3] @ T1[:3, :3].T), T2[:3, 3] - T1[:3, 3]])
    S = C1 + C2
    try:
        Si = np.linalg.inv(S)
        Cf = C1 - C1 @ Si @ C1
    except np.linalg.LinAlgError:
        return None
    sign, logdet = np.linalg.slogdet(S)
    if sign <= 0:
        return None
    delta = C1 @ Si @ d
    T = np.eye(4)
    T[:3, :3] = nearest_rotation(rotvec_to_matrix(delta[:3]) @ T1[:3, :3])
    T[:3, 3] = T1[:3, 3] + delta[3:]
    m2 = float(d @ Si @ d)
    log_agree = -0.5 * m2 - 0.5 * logdet - 3.0 * math.log(2 * math.pi)
    return T, 0.5 * (Cf + Cf.T), log_agree, m2


def fuse_hypotheses(
    a: tuple[PoseHypothesis, ...], b: tuple[PoseHypothesis, ...], *, keep: int = 2
) -> tuple[PoseHypothesis, ...]:
    """Return the hypotheses of one landmark after two sets of them (e.g. a track and a new
    view, in one frame; cov of (left rotation perturbation, position)) are fused: every pair
    (i, j) weighed by p_i q_j N(d_ij; 0, C_i + C_j), its pose the information-weighted mean;
    the `keep` best, renormalised, best first (those under DROP_PROBABILITY dropped). When no
    pair agrees (AGREE_CHI2: a different landmark, or a moved one), the newer set `b` is
    returned: the track restarts from it."""
    if not a:
        return b
    if not b:
        return a
    out: list[tuple[float, Array, Array]] = []
    closest = math.inf
    for h in a:
        for g in b:
            if h.probability <= 0 or g.probability <= 0:
                continue
            f = _gaussian_fusion(h.T, h.cov, g.T, g.cov)
            if f is None:
                continue
            T, C, la, m2 = f
            closest = min(closest, m2)
            out.append((math.log(h.probability) + math.log(g.probability) + la, T, C))
    if not out or closest > AGREE_CHI2:
        return b
    out.sort(key=lambda x: -x[0])
    out = out[:keep]
    p = probabilities(np.array([x[0] for x in out]))
    return tuple(
        PoseHypothesis(T, C, float(q))
        for (_, T, C), q in zip(out, p, strict=True)
        if q >= DROP_PROBABILITY
    )
