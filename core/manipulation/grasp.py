"""The switching grasp controller's core: gaze, the switch with hysteresis, and the
position-based "look then move" from a taught image of a planar mark.

1. Approach under a gaze constraint: while the base drives, `gaze_step` turns the arm so that
   the mark's image stays near the image centre (a rotation of the camera about its own centre,
   resolved by damped least squares on the arm's Jacobian).
2. `ModeSwitch`: approach -> look-then-move when the mark is both near (estimated distance
   below `near_m`) and large (image size above `large_px`); back only when it is far or small
   by the hysteresis margins, so noise near the thresholds does not make the mode chatter.
3. Look then move. The mark was taught once: its ideal (undistorted) pixels x* as the eye-in-hand
   camera sees it from the pre-grasp pose. The current image x gives the plane-induced
   homography x* ~ H x (core.homography.fit_homography, gold standard); its decomposition
   (core.homography.decompose_homography) gives (R, t/d, n) from the current to the taught
   camera, two-fold ambiguous and up to the unknown plane distance d. `first_look` resolves both
   with one small known camera motion M made by the arm: the candidate pair whose taught-camera
   orientation and plane normal agree between the two views wins, and d follows by least
   squares from the two taught-camera positions, which must coincide (one linear equation per
   axis). The plane (n, d) is then known in the arm's base frame, so every later look
   (`next_look`) decomposes with the known normal: one solution, metric at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import DegenerateConfiguration, InvalidInput
from core.geometry.camera import undistort_points
from core.geometry.poses import as_pose, invert_pose
from core.geometry.rotations import matrix_to_rotvec
from core.homography import PlaneMotion, decompose_homography, fit_homography
from core.manipulation.arm import DHArm

Array = NDArray[np.float64]


@dataclass
class ModeSwitch:
    """The approach / look-then-move switch with hysteresis.

    near_m, large_px: switch to "look" when the mark's estimated distance is below near_m AND
    its image size (pixels, e.g. its diagonal) above large_px; switch back to "approach" only
    when the distance exceeds near_m (1 + hysteresis) OR the size falls below
    large_px (1 - hysteresis). `switches` counts every change of mode.
    """

    near_m: float = 0.9
    large_px: float = 60.0
    hysteresis: float = 0.2
    mode: str = "approach"
    switches: int = 0

    def update(self, distance_m: float, size_px: float) -> str:
        """Return the mode after one observation (distance metres, size pixels)."""
        if self.mode == "approach":
            if distance_m < self.near_m and size_px > self.large_px:
                self.mode = "look"
                self.switches += 1
        elif distance_m > self.near_m * (1 + self.hysteresis) or size_px < self.large_px * (
            1 - self.hysteresis
        ):
            self.mode = "approach"
            self.switches += 1
        return self.mode


def gaze_step(
    arm: DHArm,
    q: ArrayLike,
    T_ee_cam: ArrayLike,
    ray: ArrayLike,
    *,
    gain: float = 0.5,
    damping: float = 1e-2,
) -> Array:
    """Return a joint step (6,) that turns the camera towards a ray (3,) in its own frame.

    The camera turns about its centre by the angle between its optical axis z and the ray,
    times `gain`: omega_c = gain * angle * (z x m) / |z x m|. In the arm's frame the end
    effector must then move with v = omega x (p_ee - p_cam) (the camera centre stays), so
    dq = J^T (J J^T + damping^2 I)^-1 (v, omega) (damped least squares; Wampler 1986).
    """
    qa = np.asarray(q, dtype=np.float64)
    X = as_pose(T_ee_cam, "T_ee_cam")
    m = np.asarray(ray, dtype=np.float64)
    m = m / np.linalg.norm(m)
    axis = np.cross([0.0, 0.0, 1.0], m)
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        return np.zeros(6)
    angle = math.atan2(s, float(m[2]))
    T_ee = arm.fk(qa)
    T_cam = T_ee @ X
    omega = T_cam[:3, :3] @ (gain * angle * axis / s)
    v = np.cross(omega, T_ee[:3, 3] - T_cam[:3, 3])
    J = arm.jacobian(qa)
    twist = np.concatenate([v, omega])
    step: Array = J.T @ np.linalg.solve(J @ J.T + damping**2 * np.eye(6), twist)
    return step


@dataclass(frozen=True)
class PlaneEstimate:
    """The mark's plane in the arm's base frame: unit normal n (3,) and offset c (m), the plane
    being {X : n . X = c}; `taught_camera` (4, 4) the pose T_arm_cam* of the camera that took
    the taught image, estimated by the look."""

    n: Array
    c: float
    taught_camera: Array


def _ideal(pixels: ArrayLike, K: Array, dist: ArrayLike | None) -> Array:
    return undistort_points(np.asarray(pixels, dtype=np.float64), K, dist, to_pixels=True)


def _motion_to_taught(
    pixels: ArrayLike, taught_ideal: Array, K: Array, dist: ArrayLike | None, normal: Array | None
) -> tuple[list[PlaneMotion], Array]:
    """Return the decompositions of x* ~ H x (current -> taught) and the ideal current pixels."""
    x = _ideal(pixels, K, dist)
    H = fit_homography(x, taught_ideal, method="gold").H
    return decompose_homography(H, K, points=x, points2=taught_ideal, normal=normal), x


def _taught_pose(F: Array, motion: PlaneMotion, d: float) -> Array:
    """Return T_arm_cam* = F [R, d t]^-1 for the current camera pose F and a decomposition."""
    Tm = np.eye(4)
    Tm[:3, :3] = motion.R
    Tm[:3, 3] = d * motion.t
    out: Array = F @ invert_pose(Tm)
    return out


def first_look(
    F1: ArrayLike,
    pixels1: ArrayLike,
    F2: ArrayLike,
    pixels2: ArrayLike,
    taught_ideal: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None = None,
) -> PlaneEstimate:
    """Return the mark's plane and the taught camera's pose from two views a known motion apart.

    F1, F2: (4, 4) the camera's poses T_arm_cam of the two views (forward kinematics and the
    hand-eye transform: their relative motion is what is known, up to the arm's accuracy);
    pixels1, pixels2: (N, 2) the mark's points as detected (distorted) in each; taught_ideal:
    (N, 2) their taught ideal pixels; K, dist: the camera's intrinsics.

    Each view's homography to the taught image has up to two physically realisable
    decompositions (R_k, u_k = t_k / d_k, n_k). For the right pair the taught camera's
    orientation R_F R^T and the normal R_F n agree between the views; with the camera-2 centre
    m = (F1^-1 F2) origin in camera-1 coordinates, d_2 = d_1 - n_1 . m, and the taught camera's
    position p_k - R_Fk R_k^T u_k d_k must coincide, which is linear in d_1.
    Raises DegenerateConfiguration when no consistent pair exists or the known motion does not
    constrain d (too small, or parallel to the plane in a way that leaves d unobservable).
    """
    A1, A2 = as_pose(F1, "F1"), as_pose(F2, "F2")
    Km = np.asarray(K, dtype=np.float64)
    t_ideal = np.asarray(taught_ideal, dtype=np.float64)
    if t_ideal.ndim != 2 or t_ideal.shape[1] != 2:
        raise InvalidInput(f"taught_ideal must be (N, 2) pixels, got {t_ideal.shape}")
    cands1, _ = _motion_to_taught(pixels1, t_ideal, Km, dist, None)
    cands2, _ = _motion_to_taught(pixels2, t_ideal, Km, dist, None)
    if not cands1 or not cands2:
        raise DegenerateConfiguration(
            "the mark's homography to the taught image has no physically realisable "
            "decomposition; check the mark's point order and the taught image"
        )
    m = (invert_pose(A1) @ A2)[:3, 3]
    best: tuple[float, PlaneMotion, PlaneMotion] | None = None
    for a in cands1:
        for b in cands2:
            Ra = A1[:3, :3] @ a.R.T
            Rb = A2[:3, :3] @ b.R.T
            rot = float(np.linalg.norm(matrix_to_rotvec(Ra.T @ Rb)))
            na, nb = A1[:3, :3] @ a.n, A2[:3, :3] @ b.n
            ang = math.acos(max(-1.0, min(1.0, float(na @ nb))))
            score = rot + ang
            if best is None or score < best[0]:
                best = (score, a, b)
    assert best is not None
    _, a, b = best
    ga = A1[:3, :3] @ a.R.T @ a.t
    gb = A2[:3, :3] @ b.R.T @ b.t
    # p1 - ga d1 = p2 - gb (d1 - n1 . m)  =>  (gb - ga) d1 = p2 - p1 + gb (n1 . m).
    coef = gb - ga
    rhs = A2[:3, 3] - A1[:3, 3] + gb * float(a.n @ m)
    if float(coef @ coef) < 1e-12:
        raise DegenerateConfiguration(
            "the known camera motion leaves the mark's distance unobservable; move the camera "
            "by a few centimetres towards or across the mark between the two views"
        )
    d1 = float(coef @ rhs / (coef @ coef))
    if not d1 > 0:
        raise DegenerateConfiguration(
            f"the estimated plane distance is {d1:.3f} m (not in front of the camera)"
        )
    n_arm = A1[:3, :3] @ a.n
    c = d1 + float(n_arm @ A1[:3, 3])
    return PlaneEstimate(n=n_arm, c=c, taught_camera=_taught_pose(A1, a, d1))


def next_look(
    F: ArrayLike,
    pixels: ArrayLike,
    taught_ideal: ArrayLike,
    plane: PlaneEstimate,
    K: ArrayLike,
    dist: ArrayLike | None = None,
) -> Array:
    """Return the taught camera's pose T_arm_cam* (4, 4) from one view F (4, 4) and the known
    plane: the decomposition with the plane's normal in the camera's frame R_F^T n (a single
    solution), made metric by the camera's distance to the plane, c - n . p_F."""
    A = as_pose(F, "F")
    n_cam = A[:3, :3].T @ plane.n
    d = plane.c - float(plane.n @ A[:3, 3])
    if not d > 0:
        raise DegenerateConfiguration("the camera is behind the mark's plane")
    Km = np.asarray(K, dtype=np.float64)
    sols, _ = _motion_to_taught(pixels, np.asarray(taught_ideal, np.float64), Km, dist, n_cam)
    return _taught_pose(A, sols[0], d)
