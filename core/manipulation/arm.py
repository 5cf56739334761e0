"""A serial arm in Denavit-Hartenberg form: forward kinematics, the geometric Jacobian, the
closed-form inverse kinematics of a wrist-partitioned (Puma-type) arm, and the arm's numerical
inverse kinematics (the solver itself is core.manipulation.numerical_ik's).

Convention: standard (distal) DH parameters, link i's transform
A_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i), theta_i = q_i + offset_i (Spong, Hutchinson &
Vidyasagar, "Robot Modeling and Control", 2006, eq. 3.10; Corke, "Robotics, Vision and Control",
2nd ed., sec. 7.1.1). Joint i turns about z_{i-1}. The end effector is the flange (frame 6)
followed by a fixed tool transform T_flange_ee. Poses are 4x4, metres and radians; batch
dimensions come first everywhere.

The closed form is for the Puma type (core.manipulation.arm_models' default arm): its last three
axes intersect at the wrist centre (a spherical wrist), so its inverse kinematics splits into
the wrist centre's position (joints 1-3) and the wrist's orientation (joints 4-6): eight
branches at most, each shifted by 2 pi where the limits allow (Paul & Zhang, "Computationally
efficient kinematics for manipulators with spherical wrists", IJRR 5(2), 1986).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import product

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.geometry.poses import as_pose, invert_pose
from core.geometry.rotations import matrix_to_rotvec, wrap_angle
from core.manipulation.numerical_ik import IKResult, levenberg_marquardt, rotvec_one

Array = NDArray[np.float64]

# The Puma's DH structure for which `ik_analytic` has a closed form.
PUMA_ALPHA = np.array([np.pi / 2, 0.0, -np.pi / 2, np.pi / 2, -np.pi / 2, 0.0])


@dataclass(frozen=True, eq=False)
class DHArm:
    """A 6-joint revolute arm in standard DH form.

    a, d: (6,) metres; alpha, offset: (6,) radians; limits: (6, 2) radians (lower, upper);
    tool: (4, 4) T_flange_ee; home: (6,) a configuration inside the limits away from
    singularities, the first start of the numerical IK when no q0 is given.
    """

    name: str
    a: Array
    d: Array
    alpha: Array
    offset: Array
    limits: Array
    tool: Array = field(default_factory=lambda: np.eye(4))
    home: Array = field(default_factory=lambda: np.zeros(6))

    def __post_init__(self) -> None:
        for key in ("a", "d", "alpha", "offset", "home"):
            v = np.asarray(getattr(self, key), dtype=np.float64)
            if v.shape != (6,) or not np.all(np.isfinite(v)):
                raise InvalidInput(f"DHArm.{key} must be 6 finite values, got shape {v.shape}")
            object.__setattr__(self, key, v)
        lim = np.asarray(self.limits, dtype=np.float64)
        if lim.shape != (6, 2) or not np.all(lim[:, 0] < lim[:, 1]):
            raise InvalidInput("DHArm.limits must be (6, 2) with lower < upper for every joint")
        object.__setattr__(self, "limits", lim)
        object.__setattr__(self, "tool", as_pose(self.tool, "DHArm.tool"))
        object.__setattr__(self, "_tool_inv", invert_pose(self.tool))
        # A_i = K0 + cos(theta_i) KC + sin(theta_i) KS (module docstring's A_i, expanded).
        ca, sa = np.cos(self.alpha), np.sin(self.alpha)
        k0, kc, ks = np.zeros((6, 4, 4)), np.zeros((6, 4, 4)), np.zeros((6, 4, 4))
        k0[:, 2, 1], k0[:, 2, 2], k0[:, 2, 3], k0[:, 3, 3] = sa, ca, self.d, 1.0
        kc[:, 0, 0], kc[:, 0, 3], kc[:, 1, 1], kc[:, 1, 2] = 1.0, self.a, ca, -sa
        ks[:, 0, 1], ks[:, 0, 2], ks[:, 1, 0], ks[:, 1, 3] = -ca, sa, 1.0, self.a
        object.__setattr__(self, "_dh_tensors", (k0, kc, ks))
        # Plain floats for the scalar kinematics of the numerical IK.
        object.__setattr__(self, "_off", [float(v) for v in self.offset])
        object.__setattr__(self, "_cal", [float(v) for v in ca])
        object.__setattr__(self, "_sal", [float(v) for v in sa])
        object.__setattr__(self, "_al", [float(v) for v in self.a])
        object.__setattr__(self, "_dl", [float(v) for v in self.d])
        object.__setattr__(self, "_tool_t", [float(v) for v in self.tool[:3, 3]])
        tool_r = self.tool[:3, :3]
        object.__setattr__(
            self, "_tool_r", None if np.array_equal(tool_r, np.eye(3)) else tool_r.ravel().tolist()
        )

    # ----------------------------------------------------------------------------------------
    # Forward kinematics and Jacobian

    def _check_q(self, q: ArrayLike) -> Array:
        a = np.asarray(q, dtype=np.float64)
        if a.shape[-1:] != (6,) or not np.all(np.isfinite(a)):
            raise InvalidInput(f"q must be finite joint values of shape (..., 6), got {a.shape}")
        return a

    def link_transforms(self, q: ArrayLike) -> Array:
        """Return the six DH link transforms A_i (..., 6, 4, 4) at joint values q (..., 6)."""
        th = self._check_q(q) + self.offset
        # A = K0 + cos(theta) KC + sin(theta) KS: three constant (6, 4, 4) tensors, so a batch
        # costs five numpy calls whatever its size.
        k0, kc, ks = self._dh_tensors  # type: ignore[attr-defined]
        out: Array = k0 + np.cos(th)[..., None, None] * kc + np.sin(th)[..., None, None] * ks
        return out

    def frames(self, q: ArrayLike) -> Array:
        """Return T_0_i for i = 0..6 and the end effector, shape (..., 8, 4, 4): frame 0 is the
        arm's base (identity), frame 6 the flange, the last the end effector (flange @ tool)."""
        A = self.link_transforms(q)
        out = np.empty((*A.shape[:-3], 8, 4, 4))
        out[..., 0, :, :] = np.eye(4)
        cur = A[..., 0, :, :]
        out[..., 1, :, :] = cur
        for i in range(1, 6):
            cur = np.matmul(cur, A[..., i, :, :])
            out[..., i + 1, :, :] = cur
        out[..., 7, :, :] = np.matmul(cur, self.tool)
        return out

    def fk(self, q: ArrayLike) -> Array:
        """Return the end effector's pose T_base_ee (..., 4, 4) in the arm's base frame at joint
        values q (..., 6): A_1 ... A_6 @ tool."""
        return self.frames(q)[..., 7, :, :]

    def jacobian(self, q: ArrayLike) -> Array:
        """Return the geometric Jacobian (..., 6, 6) of the end effector in the arm's base
        frame, rows (v, omega): column i = (z_{i-1} x (p_ee - o_{i-1}), z_{i-1})
        (Spong et al. 2006, eq. 4.63-4.64)."""
        return _geometric_jacobian(self.frames(q))

    def within_limits(self, q: ArrayLike, tol: float = 0.0) -> NDArray[np.bool_]:
        """Return whether joint values q (..., 6) lie inside the limits (widened by tol)."""
        qa = np.asarray(q, dtype=np.float64)
        lo, hi = self.limits[:, 0] - tol, self.limits[:, 1] + tol
        return np.all((qa >= lo) & (qa <= hi), axis=-1)

    def manipulability(self, q: ArrayLike) -> Array:
        """Return Yoshikawa's manipulability sqrt(det(J J^T)) (...,) at q (..., 6)."""
        J = self.jacobian(q)
        return np.sqrt(np.abs(np.linalg.det(J @ np.swapaxes(J, -1, -2))))

    # ----------------------------------------------------------------------------------------
    # Closed-form inverse kinematics (Puma-type spherical wrist)

    @property
    def has_closed_form(self) -> bool:
        """True when the geometry is the Puma type `ik_analytic` solves: alpha = (pi/2, 0,
        -pi/2, pi/2, -pi/2, 0), a1 = a4 = a5 = a6 = 0, d2 = d5 = d6 = 0, zero offsets."""
        return bool(
            np.allclose(self.alpha, PUMA_ALPHA, atol=1e-12)
            and np.all(self.a[[0, 3, 4, 5]] == 0)
            and np.all(self.d[[1, 4, 5]] == 0)
            and np.all(self.offset == 0)
            and self.a[1] > 0
        )

    def ik_analytic(self, T: ArrayLike, *, include_singular: bool = True) -> list[Array]:
        """Return every joint vector (list of (6,)) within the limits whose fk equals T.

        T: (4, 4) T_base_ee. Wrist centre p_w = origin of T @ tool^-1 (the flange; d6 = 0).
        Shoulder: -s1 px + c1 py = -d3 gives two q1; elbow: the planar two-link equation
        a3 c3 - d4 s3 = (x^2 + y^2 - a2^2 - a3^2 - d4^2) / (2 a2) two q3, then q2 by atan2;
        wrist: R_3^6 = R_0^3^T R = Rz(q4) Ry(-q5) Rz(q6), a ZYZ Euler triple with two branches
        (q5 and -q5). Each of the up to eight branches, wrapped to (-pi, pi], is repeated with
        every 2 pi shift that stays within the limits. At the wrist singularity (q5 = 0) only
        q4 + q6 is determined; the branch with q4 = 0 (or the nearest limit) is returned, and
        with `include_singular=False` none. Unreachable targets give an empty list.
        Raises InvalidInput when the arm is not of the Puma type (`has_closed_form`).
        """
        if not self.has_closed_form:
            raise InvalidInput(
                f"arm {self.name!r} has no closed-form inverse kinematics (not a Puma-type "
                "spherical-wrist geometry); use ik() instead"
            )
        Tm = as_pose(T, "T")
        if Tm.shape != (4, 4):
            raise InvalidInput(f"T must be one (4, 4) pose, got {Tm.shape}")
        Tf = Tm @ self._tool_inv  # type: ignore[attr-defined]
        R06 = Tf[:3, :3]
        px, py, pz = Tf[:3, 3]
        d1, a2, a3 = self.d[0], self.a[1], self.a[2]
        d3, d4 = self.d[2], self.d[3]
        pz = pz - d1
        sols: list[Array] = []
        r2 = px * px + py * py
        if r2 < d3 * d3:
            return sols
        rho = math.sqrt(r2 - d3 * d3)
        phi = math.atan2(py, px)
        for s_arm in (1.0, -1.0):
            # r sin(phi - q1) = -d3 with r cos(phi - q1) = s_arm rho.
            q1 = phi - math.atan2(-d3, s_arm * rho)
            c1, s1 = math.cos(q1), math.sin(q1)
            x2 = c1 * px + s1 * py
            y2 = pz
            kk = (x2 * x2 + y2 * y2 - a2 * a2 - a3 * a3 - d4 * d4) / (2.0 * a2)
            rr = math.hypot(a3, d4)
            cval = kk / rr
            if abs(cval) > 1.0 + 1e-12:
                continue
            cval = max(-1.0, min(1.0, cval))
            psi = math.atan2(d4, a3)
            for s_elbow in (1.0, -1.0):
                q3 = s_elbow * math.acos(cval) - psi
                c3, s3 = math.cos(q3), math.sin(q3)
                u = a2 + a3 * c3 - d4 * s3
                v = a3 * s3 + d4 * c3
                q2 = math.atan2(y2, x2) - math.atan2(v, u)
                R03 = self.fk_partial(np.array([q1, q2, q3]))[:3, :3]
                M = R03.T @ R06
                s5a = math.hypot(M[0, 2], M[1, 2])
                singular = s5a < 1e-10
                if singular and not include_singular:
                    continue
                for s_wrist in (1.0, -1.0) if not singular else (1.0,):
                    if singular:
                        q5 = 0.0 if M[2, 2] > 0 else math.pi
                        q4 = float(np.clip(0.0, self.limits[3, 0], self.limits[3, 1]))
                        # Rz(q6) = Ry(q5) Rz(q4)^T M.
                        N = _rot_y(q5) @ _rot_z(q4).T @ M
                        q6 = math.atan2(N[1, 0], N[0, 0])
                    else:
                        s5 = s_wrist * s5a
                        q5 = -math.atan2(s5, M[2, 2])
                        # M02 = -c4 s5', M12 = -s4 s5', M20 = s5' c6, M21 = -s5' s6,
                        # s5' = sin q5.
                        sq5 = math.sin(q5)
                        q4 = math.atan2(-M[1, 2] / sq5, -M[0, 2] / sq5)
                        q6 = math.atan2(-M[2, 1] / sq5, M[2, 0] / sq5)
                    base = np.array([q1, q2, q3, q4, q5, q6])
                    sols.extend(self._shifted(-wrap_angle(-base)))
        return _unique(sols)

    def fk_partial(self, q123: Array) -> Array:
        """Return T_0_3 (4, 4) for the first three joint values."""
        q = np.zeros(6)
        q[:3] = q123
        A = self.link_transforms(q)
        return A[0] @ A[1] @ A[2]

    def _shifted(self, q: Array) -> list[Array]:
        """Return q with every combination of 2 pi shifts per joint that lies within limits."""
        options = []
        for i in range(6):
            lo, hi = self.limits[i]
            k_lo = math.ceil((lo - q[i]) / (2 * math.pi) - 1e-12)
            k_hi = math.floor((hi - q[i]) / (2 * math.pi) + 1e-12)
            vals = [q[i] + 2 * math.pi * k for k in range(k_lo, k_hi + 1)]
            vals = [min(max(v, lo), hi) for v in vals]
            if not vals:
                return []
            options.append(vals)
        return [np.array(c) for c in product(*options)]

    # ----------------------------------------------------------------------------------------
    # Numerical inverse kinematics

    def ik(
        self,
        T: ArrayLike,
        q0: ArrayLike | None = None,
        *,
        tol: float = 1e-10,
        max_iterations: int = 1000,
        starts: int = 8,
        per_start: int = 20,
        rng: np.random.Generator | int | None = 0,
    ) -> IKResult:
        """Return joint values reaching T (4, 4) by Levenberg-Marquardt on the pose error.

        Minimises 0.5 ||e(q)||^2, e = (p* - p(q), log(R* R(q)^T)) (metres, radians), with
        steps (J^T J + mu I) dq = J^T e, mu adapted per start (divided by 3 on success,
        multiplied by 4 on failure; Madsen, Nielsen & Tingleff 2004, sec. 3.2); a joint pushed
        past a limit is shifted by 2 pi when that brings it inside, else clipped. Starts, one
        after the other, each for at most `per_start` iterations: q0 (when given), then the
        configurations of a fixed seed bank whose poses are nearest T (`starts` in all), then
        random configurations within the limits from `rng`. A start that stalls (a local
        minimum) or stays pinned against a limit gives way to the next. Stops when a start
        reaches position and rotation errors <= tol (success) or after `max_iterations` in
        all, returning the best start. The errors reported are recomputed from fk, not the
        solver's residual.
        """
        Tm = as_pose(T, "T")
        if Tm.shape != (4, 4):
            raise InvalidInput(f"T must be one (4, 4) pose, got {Tm.shape}")
        gen: np.random.Generator | None = None
        lo, hi = self.limits[:, 0], self.limits[:, 1]
        k = max(int(starts), 1)
        if q0 is None:
            seeds = self._nearest_seeds(Tm, k)
        else:
            seeds = [np.clip(self._check_q(q0), lo, hi), *self._nearest_seeds(Tm, k - 1)]
        first = seeds[0]
        iters = 0
        restarts = 0
        best_q, best_cost = first, np.inf
        ones = np.ones(6)
        target = (*Tm[:3, 3].tolist(), *Tm[:3, :3].ravel().tolist())

        def residual(q: Array) -> tuple[Array, Array, float, float]:
            return self._residual_one(q, target)

        while iters < max_iterations:
            if seeds:
                q_start = seeds.pop(0)
            else:
                # Created only when needed: most solves never draw a random start.
                gen = np.random.default_rng(rng) if gen is None else gen
                q_start = gen.uniform(lo, hi)
                restarts += 1
            budget = min(per_start, max_iterations - iters)
            q, cost, used, ok = levenberg_marquardt(residual, q_start, lo, hi, ones, tol, budget)
            iters += used
            if cost < best_cost:
                best_q, best_cost = q, cost
            if ok:
                break
        # The true errors, from forward kinematics at the answer (the scalar path, which the
        # tests check against the batched fk to 1e-14).
        p, R, _ = self._kinematics_one(best_q)
        dp = float(np.linalg.norm(p - Tm[:3, 3]))
        dr = float(np.linalg.norm(rotvec_one(R.T @ Tm[:3, :3])))
        return IKResult.from_errors(best_q, dp, dr, tol, iters, restarts)

    def _nearest_seeds(self, T: Array, k: int) -> list[Array]:
        """Return the k configurations of a fixed bank (1024 configurations drawn uniformly
        within the limits, seed 0) whose end-effector poses are nearest T (squared position
        distance plus 0.09 m^2 per unit of squared rotation-matrix difference): LM starts that
        usually lie in the target's basin, so restarts are rare. (On the default arm, 1024
        saves a tenth of the iterations of 512; larger banks save less than they cost.)"""
        if k <= 0:
            return []
        bank = getattr(self, "_seed_bank", None)
        if bank is None:
            qs = np.random.default_rng(0).uniform(self.limits[:, 0], self.limits[:, 1], (1024, 6))
            Ts = self.fk(qs)
            feats = np.concatenate([Ts[:, :3, 3], 0.3 * Ts[:, :3, :3].reshape(-1, 9)], axis=1)
            bank = (qs, feats)
            object.__setattr__(self, "_seed_bank", bank)
        qs, feats = bank
        f = np.concatenate([T[:3, 3], 0.3 * T[:3, :3].ravel()])
        dist = np.einsum("ij,ij->i", feats - f, feats - f)
        k = min(k, len(qs))
        idx = np.argpartition(dist, k - 1)[:k]
        idx = idx[np.argsort(dist[idx])]
        return [qs[i].copy() for i in idx]

    def _kinematics_one(self, q: Array) -> tuple[Array, Array, Array]:
        """Return (position (3,), rotation (3, 3), Jacobian (6, 6)) of one configuration, by
        scalar arithmetic: for one small chain, Python floats beat numpy's per-call cost."""
        p, r, jac = self._kinematics_floats(q)
        R = np.array(r).reshape(3, 3) @ self.tool[:3, :3]
        return np.array(p), R, np.array(jac).T

    def _residual_one(
        self, q: Array, target: tuple[float, ...]
    ) -> tuple[Array, Array, float, float]:
        """Return the pose error e (6,) = (p* - p, log(R* R^T)), the Jacobian (6, 6) and the
        squared position and rotation errors at q, for a target given as 12 floats (p* then
        R* row-major): the numerical IK's inner step, in Python floats."""
        (x, y, z), r, jac = self._kinematics_floats(q)
        tr = self._tool_r  # type: ignore[attr-defined]
        if tr is not None:  # R = R_flange R_tool (row-major)
            r = [
                sum(r[3 * i + k] * tr[3 * k + j] for k in range(3))
                for i in range(3)
                for j in range(3)
            ]
        px, py, pz, t0, t1, t2, t3, t4, t5, t6, t7, t8 = target
        # M = R* R^T.
        m00 = t0 * r[0] + t1 * r[1] + t2 * r[2]
        m11 = t3 * r[3] + t4 * r[4] + t5 * r[5]
        m22 = t6 * r[6] + t7 * r[7] + t8 * r[8]
        m21 = t6 * r[3] + t7 * r[4] + t8 * r[5]
        m12 = t3 * r[6] + t4 * r[7] + t5 * r[8]
        m02 = t0 * r[6] + t1 * r[7] + t2 * r[8]
        m20 = t6 * r[0] + t7 * r[1] + t8 * r[2]
        m10 = t3 * r[0] + t4 * r[1] + t5 * r[2]
        m01 = t0 * r[3] + t1 * r[4] + t2 * r[5]
        cos_t = (m00 + m11 + m22 - 1.0) * 0.5
        if cos_t < -0.99:  # near pi: the general formula (rare, far from the answer)
            M = np.array([[m00, m01, m02], [m10, m11, m12], [m20, m21, m22]])
            wx, wy, wz = matrix_to_rotvec(M).tolist()
        else:
            theta = math.acos(min(1.0, cos_t))
            f = 0.5 + theta * theta / 12.0 if theta < 1e-6 else theta / (2.0 * math.sin(theta))
            wx, wy, wz = f * (m21 - m12), f * (m02 - m20), f * (m10 - m01)
        ex, ey, ez = px - x, py - y, pz - z
        e = np.array([ex, ey, ez, wx, wy, wz])
        return e, np.array(jac).T, ex * ex + ey * ey + ez * ez, wx * wx + wy * wy + wz * wz

    def _kinematics_floats(
        self, q: Array
    ) -> tuple[tuple[float, float, float], list[float], list[tuple[float, ...]]]:
        """Return the end effector's position, the flange's rotation (9 floats, row-major) and
        the Jacobian's columns (6 tuples of 6) at q, in Python floats."""
        x = y = z = 0.0
        r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]  # row-major R
        axes = []
        origins = []
        for i in range(6):
            axes.append((r[2], r[5], r[8]))
            origins.append((x, y, z))
            th = q[i] + self._off[i]  # type: ignore[attr-defined]
            c, s = math.cos(th), math.sin(th)
            ca, sa = self._cal[i], self._sal[i]  # type: ignore[attr-defined]
            a, d = self._al[i], self._dl[i]  # type: ignore[attr-defined]
            # Columns of R Rz(theta): c0 = c r0 + s r1, c1 = -s r0 + c r1, c2 = r2.
            c00, c01, c02 = c * r[0] + s * r[1], c * r[3] + s * r[4], c * r[6] + s * r[7]
            c10, c11, c12 = -s * r[0] + c * r[1], -s * r[3] + c * r[4], -s * r[6] + c * r[7]
            r2 = (r[2], r[5], r[8])
            x += a * c00 + d * r2[0]
            y += a * c01 + d * r2[1]
            z += a * c02 + d * r2[2]
            # Then Rx(alpha): c1' = ca c1 + sa c2, c2' = -sa c1 + ca c2.
            n1 = (ca * c10 + sa * r2[0], ca * c11 + sa * r2[1], ca * c12 + sa * r2[2])
            n2 = (-sa * c10 + ca * r2[0], -sa * c11 + ca * r2[1], -sa * c12 + ca * r2[2])
            r = [c00, n1[0], n2[0], c01, n1[1], n2[1], c02, n1[2], n2[2]]
        tx, ty, tz = self._tool_t  # type: ignore[attr-defined]
        x += r[0] * tx + r[1] * ty + r[2] * tz
        y += r[3] * tx + r[4] * ty + r[5] * tz
        z += r[6] * tx + r[7] * ty + r[8] * tz
        jac: list[tuple[float, ...]] = []
        for (ax, ay, az), (ox, oy, oz) in zip(axes, origins, strict=True):
            dx, dy, dz = x - ox, y - oy, z - oz
            jac.append((ay * dz - az * dy, az * dx - ax * dz, ax * dy - ay * dx, ax, ay, az))
        return (x, y, z), r, jac


def _geometric_jacobian(F: Array) -> Array:
    """Return the geometric Jacobian (..., 6, 6) from frames (..., 8, 4, 4) of `DHArm.frames`."""
    z = F[..., :6, :3, 2]  # axes z_0 .. z_5
    d = F[..., 7, None, :3, 3] - F[..., :6, :3, 3]
    J = np.empty((*F.shape[:-3], 6, 6))
    # z x d, written out: np.cross costs several times more on small batches.
    J[..., 0, :] = z[..., 1] * d[..., 2] - z[..., 2] * d[..., 1]
    J[..., 1, :] = z[..., 2] * d[..., 0] - z[..., 0] * d[..., 2]
    J[..., 2, :] = z[..., 0] * d[..., 1] - z[..., 1] * d[..., 0]
    J[..., 3:, :] = np.swapaxes(z, -1, -2)
    return J


def _rot_z(t: float) -> Array:
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_y(t: float) -> Array:
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _unique(sols: list[Array], tol: float = 1e-9) -> list[Array]:
    out: list[Array] = []
    for s in sols:
        if not any(np.max(np.abs(s - o)) < tol for o in out):
            out.append(s)
    return out
