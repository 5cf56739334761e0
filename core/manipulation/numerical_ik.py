"""Numerical inverse kinematics: Levenberg-Marquardt on the pose error with joint limits, the
pose residual it minimises and the result it returns (`IKResult`). Shared by the arm
(`DHArm.ik`) and the whole mobile manipulator (`MobileManipulator.ik`), each of which supplies
its own kinematics."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.geometry.rotations import matrix_to_rotvec

Array = NDArray[np.float64]


@dataclass(frozen=True)
class IKResult:
    """A numerical inverse kinematics solution.

    q: (n,) joint values (radians, metres for prismatic base joints); success: both true errors
    within the tolerance; position_error (m) and rotation_error (rad): the errors of fk(q)
    against the target, computed afresh from forward kinematics (not the solver's residual);
    iterations: LM iterations over all starts; restarts: random starts used after the first.
    """

    q: Array
    success: bool
    position_error: float
    rotation_error: float
    iterations: int
    restarts: int

    @classmethod
    def from_errors(
        cls,
        q: Array,
        dp: float | Array,
        dr: float | Array,
        tol: float,
        iterations: int,
        restarts: int,
    ) -> IKResult:
        """Return the result at q whose true errors are dp (m) and dr (rad): a success when
        both are within tol."""
        return cls(
            q=q,
            success=bool(dp <= tol and dr <= tol),
            position_error=float(dp),
            rotation_error=float(dr),
            iterations=iterations,
            restarts=restarts,
        )


def _into_limits(q: Array, lo: Array, hi: Array, periodic: NDArray[np.bool_]) -> Array:
    """Return q with each out-of-limit periodic joint shifted by the multiple of 2 pi that
    brings it inside [lo, hi] (the same orientation of that link), and what is still outside
    clipped to the nearest limit."""
    out = (q < lo) | (q > hi)
    if not out.any():
        return q
    r = q.copy()
    two_pi = 2.0 * math.pi
    k = np.where(q < lo, np.ceil((lo - q) / two_pi), np.floor((hi - q) / two_pi))
    shifted = q + two_pi * k
    ok = out & periodic & (shifted >= lo) & (shifted <= hi)
    r[ok] = shifted[ok]
    return np.clip(r, lo, hi)


def rotvec_one(M: Array) -> Array:
    """Return the rotation vector (3,) of one rotation matrix (matrix_to_rotvec's formula,
    its near-pi branch delegated)."""
    cos_t = (M[0, 0] + M[1, 1] + M[2, 2] - 1.0) * 0.5
    if cos_t < -0.99:
        out: Array = matrix_to_rotvec(M)
        return out
    theta = math.acos(min(1.0, cos_t))
    w = np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
    if theta < 1e-6:
        return w * (0.5 + theta * theta / 12.0)
    return w * (theta / (2.0 * math.sin(theta)))


def pose_residual(
    kinematics: Callable[[Array], tuple[Array, Array, Array]], T_target: Array
) -> Callable[[Array], tuple[Array, Array, float, float]]:
    """Return residual(q) -> (e, J, |e_p|^2, |e_r|^2) for `levenberg_marquardt` from
    kinematics(q) -> (p (3,), R (3, 3), J (6, n)): e = (p* - p, log(R* R^T)) towards T_target
    (4, 4)."""
    pt, Rt = T_target[:3, 3], T_target[:3, :3]

    def residual(q: Array) -> tuple[Array, Array, float, float]:
        p, R, J = kinematics(q)
        e = np.concatenate([pt - p, rotvec_one(Rt @ R.T)])
        return e, J, float(e[:3] @ e[:3]), float(e[3:] @ e[3:])

    return residual


def levenberg_marquardt(
    residual: Callable[[Array], tuple[Array, Array, float, float]],
    q0: Array,
    lo: Array,
    hi: Array,
    D: Array,
    tol: float,
    max_iterations: int,
    periodic: NDArray[np.bool_] | None = None,
    pinned_patience: int = 3,
) -> tuple[Array, float, int, bool]:
    """Run Levenberg-Marquardt from q0 on the pose error; return (q, cost, iterations, reached).

    residual(q) -> (e (6,), J (6, n), |e_p|^2, |e_r|^2), e the pose error (`pose_residual`).
    Steps (J^T J + mu D) dq = J^T e, brought into [lo, hi] by `_into_limits` (periodic joints:
    all revolute by default); mu / 3 after a step that lowers the cost, mu * 4 after one that
    does not. Gives up (reached False) when mu exceeds 1e4, when 12 steps in a row gain less
    than 0.1 %, or when more than `pinned_patience` steps in a row end with a joint clipped
    to a limit: a local minimum, or a branch whose solution lies past a limit, where a new
    start does better than more iterations (on the default arm, a start pinned for 3 steps
    almost never recovers, and stopping there halves the iterations of the starts that fail).
    """
    q = q0.copy()
    e, J, ep2, er2 = residual(q)
    E = ep2 + er2
    mu = 1e-3
    stall = 0
    pinned = 0
    tol2 = tol * tol
    it = 0
    n = q.shape[0]
    diag = (np.arange(n), np.arange(n))
    lo_l, hi_l = lo.tolist(), hi.tolist()
    wraps = np.ones(n, dtype=bool) if periodic is None else periodic
    while it < max_iterations:
        if ep2 <= tol2 and er2 <= tol2:
            return q, E, it, True
        it += 1
        Jt = J.T
        A = Jt @ J
        A[diag] += mu * D
        qn = q + np.linalg.solve(A, Jt @ e)
        # The limit check in Python floats: for a few joints it costs less than numpy's.
        clipped = False
        if any(v < a or v > b for v, a, b in zip(qn.tolist(), lo_l, hi_l, strict=True)):
            qn = _into_limits(qn, lo, hi, wraps)
            clipped = any(v == a or v == b for v, a, b in zip(qn.tolist(), lo_l, hi_l, strict=True))
        en, Jn, epn, ern = residual(qn)
        En = epn + ern
        if En < E:
            stall = 0 if En < 0.999 * E else stall + 1
            q, J, e, E, ep2, er2 = qn, Jn, en, En, epn, ern
            mu = max(mu / 3.0, 1e-15)
        else:
            stall += 1
            mu *= 4.0
        pinned = pinned + 1 if clipped else 0
        if mu > 1e4 or stall > 12 or pinned > pinned_patience:
            break
    return q, E, it, ep2 <= tol2 and er2 <= tol2
