"""The arm's eye-in-hand camera on the twin: its own calibration and the views of a hand-eye
calibration.

* `eye_camera_intrinsics(rng)`: the camera's own calibration (Zhang on rendered chessboard views,
  core.sim.intrinsics); no estimate reads its true lens (EYE_K, EYE_DIST: image formation and
  scoring only).
* `hand_eye_views(...)`: the arm shows the camera a chessboard lying on the dining table from n
  poses; each view's pixels are either the rendered image's detected corners (`rendered=True`:
  the twin's renderer draws the board as seen from the camera's pose, with sensor noise, and
  core.calibration.find_chessboard detects it) or the true projections plus Gaussian noise of
  `sigma_px`. The calibration inputs are only the arm's forward kinematics at its joint
  readings and each view's pose estimated from its pixels (core.calibration.estimate_plane_pose)
  on the camera's calibrated intrinsics; the true hand-eye transform, board pose and lens are
  kept apart for scoring.
* `hand_eye_error(...)`: one method's hand-eye estimate scored against the true transform.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from core.calibration import Chessboard, board_object_points, estimate_plane_pose, find_chessboard
from core.errors import InvalidInput, PatternNotFound
from core.geometry.camera import project_points
from core.geometry.poses import invert_pose, planar_pose
from core.geometry.rotations import matrix_to_rotvec
from core.manipulation import (
    HandEyeCalibration,
    MobileManipulator,
    calibrate_hand_eye,
    default_manipulator,
    pose_error,
)
from core.sim.intrinsics import NOISE as INTRINSICS_NOISE
from core.sim.intrinsics import RenderedCalibration, calibrate_from_board_views
from core.sim.render import Renderer, SensorNoise, camera_at
from core.sim.render.landmarks import LandmarkCamera
from core.sim.scene import Board, CeilingCamera, default_scene

Array = NDArray[np.float64]

# The eye-in-hand camera's true lens: 640x480, mildly wide, barrel distortion. It only forms
# the images and scores: every estimate uses the camera's own calibration
# (eye_camera_intrinsics).
EYE_K = np.array([[520.0, 0.0, 319.5], [0.0, 520.0, 239.5], [0.0, 0.0, 1.0]])
EYE_DIST = np.array([-0.08, 0.02, 0.0, 0.0, 0.0])
EYE_SIZE = (640, 480)
# A printed 8 x 5 (inner corners) chessboard with 25 mm squares (8 + 5 odd: the detector can
# tell its first corner from its last).
BOARD = Board(inner_corners=(8, 5), square_size=0.025, margin=1.0)
# The robot parked in front of the dining table (6.3, 1.9), facing it (+y).
PARK = np.array([6.3, 1.02, math.pi / 2])
TABLE_TOP = 0.75
# The two-group hand-eye method's first group: of the views, this many (after the first) are
# pure translations of the first view's camera, along its x, y, z axes in turn, by
# TRANSLATION_M metres; with the first view they give 6 motions without rotation.
TRANSLATIONS = 3
TRANSLATION_M = (0.04, 0.07)


@dataclass(frozen=True)
class HandEyeMethodError:
    """One method's hand-eye estimate against the truth: rotation error degrees (angle of
    R_est^T R_true), translation error millimetres, and its own predicted standard deviations."""

    method: str
    rotation_error_deg: float
    translation_error_mm: float
    rotation_std_deg: float
    translation_std_mm: float


def hand_eye_error(
    method: str, X: Array, true_X: Array, rotation_std_deg: float, translation_std_m: float
) -> HandEyeMethodError:
    """Return the errors of hand-eye estimate `X` (4x4 T_ee_camera) of `method` against the
    true `true_X`, with the estimate's own standard deviations (degrees, metres; scoring)."""
    dp, dr = pose_error(X, true_X)
    return HandEyeMethodError(
        method=method,
        rotation_error_deg=math.degrees(float(dr)),
        translation_error_mm=1e3 * float(dp),
        rotation_std_deg=rotation_std_deg,
        translation_std_mm=1e3 * translation_std_m,
    )


@dataclass(frozen=True)
class HandEyeViews:
    """The inputs of one hand-eye calibration and the truth kept apart for scoring.

    q (n, 6): joint readings; T_base_ee (n, 4, 4): the arm's fk at q (arm base frame);
    T_cam_target (n, 4, 4): each view's board pose estimated from its pixels; object_points
    (M, 3) board frame; image_points (n, M, 2) pixels; K, dist: the eye-in-hand camera's
    calibrated intrinsics (`intrinsics_from` says how); source: "rendered" (detected corners) or
    "projected" (true projections plus noise); translations: how many views after the first are
    pure translations of it (the two-group method's first group). true_X (4, 4)
    T_ee_cam and true_T_base_target (4, 4): scoring only.
    """

    q: Array
    T_base_ee: Array
    T_cam_target: Array
    object_points: Array
    image_points: Array
    K: Array
    dist: Array
    source: str
    intrinsics_from: str
    translations: int
    true_X: Array = field(repr=False)
    true_T_base_target: Array = field(repr=False)

    def calibrate(self, method: str, *, refine: bool = False) -> HandEyeCalibration:
        """Return the hand-eye calibration of these views by `method` (core.manipulation's
        calibrate_hand_eye); with `refine`, refined by the board corners' reprojection error on
        the calibrated intrinsics."""
        if not refine:
            return calibrate_hand_eye(self.T_base_ee, self.T_cam_target, method=method)
        return calibrate_hand_eye(
            self.T_base_ee,
            self.T_cam_target,
            method=method,
            object_points=self.object_points,
            image_points=self.image_points,
            K=self.K,
            dist=self.dist,
        )


def board_on_table(manipulator: MobileManipulator, park: Array = PARK) -> tuple[Array, Array]:
    """Return (T_world_board, T_arm_board) of the chessboard lying face up on the dining table,
    0.62 m ahead of the parked base, in the renderer's board convention (origin at the first
    inner corner, z into the board)."""
    cols, rows = BOARD.inner_corners
    s = BOARD.square_size
    T = np.eye(4)
    # x along world +x, y along world -y: z = x cross y = -Z, the printed face looks up.
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    centre = np.array([park[0], park[1] + 0.62, TABLE_TOP + 1e-3])
    T[:3, 3] = centre - T[:3, :3] @ np.array([(cols - 1) * s / 2, (rows - 1) * s / 2, 0.0])
    T_world_arm = planar_pose(park) @ manipulator.T_base_arm
    return T, invert_pose(T_world_arm) @ T


def _look_pose(rng: np.random.Generator, centre: Array, normal: Array) -> Array:
    """Return a camera pose T (4, 4) 0.28-0.42 m from `centre`, its optical axis within 30 deg
    of -normal, aimed within 2 cm of the centre, rolled at random."""
    tilt = rng.uniform(0.0, math.radians(30.0))
    az = rng.uniform(-math.pi, math.pi)
    a = np.cross(normal, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    direction = math.cos(tilt) * normal + math.sin(tilt) * (math.cos(az) * a + math.sin(az) * b)
    pos = centre + rng.uniform(0.28, 0.42) * direction
    aim = centre + rng.normal(0.0, 0.02, 3)
    z = aim - pos
    z /= np.linalg.norm(z)
    x = np.cross(z, rng.normal(size=3))
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = pos
    return T


def hand_eye_views(
    rng: np.random.Generator,
    *,
    views: int = 15,
    sigma_px: float = 0.5,
    rendered: bool = False,
    manipulator: MobileManipulator | None = None,
    renderer: Renderer | None = None,
    noise: SensorNoise | None = None,
    intrinsics: RenderedCalibration | None = None,
    translations: int | None = None,
) -> HandEyeViews:
    """Return `views` views of the table's chessboard from reachable arm poses.

    Each view: a camera pose drawn by `_look_pose`, kept when the arm's closed-form IK reaches
    it within limits (the branch nearest the home configuration) and every corner is inside the
    image with a 20 px margin. Pixels: the true projections, or the corners detected in the
    rendered image (`rendered`, with `noise`, default SensorNoise()), plus N(0, sigma_px^2) per
    axis in both cases (the detector alone is far more precise than the 0.5 px spec 05 names).
    Each view's board pose is estimated on the camera's calibrated intrinsics (`intrinsics`,
    default: calibrated first from `rng`, eye_camera_intrinsics), never on its true lens.

    Views 1 to `translations` (default TRANSLATIONS, fewer when that would leave under 3 general
    views) are the two-group method's first group: the arm translates the first view's camera
    without turning it (along its x, y, z axes in turn, by TRANSLATION_M, each
    kept when the IK reaches it and the board stays in view); the others are the general
    motions drawn by `_look_pose`.
    """
    if views < 3:
        raise InvalidInput(f"views must be >= 3, got {views}")
    if translations is None:
        translations = min(TRANSLATIONS, views - 3)
    if not 0 <= translations <= views - 3:
        raise InvalidInput(f"translations must be 0..views - 3 ({views - 3}), got {translations}")
    cal = intrinsics if intrinsics is not None else eye_camera_intrinsics(rng)
    mm = manipulator if manipulator is not None else default_manipulator()
    X = mm.T_ee_camera
    T_world_board, W = board_on_table(mm)
    P = board_object_points(Chessboard(*BOARD.inner_corners), BOARD.square_size)
    centre = W[:3, :3] @ P.mean(axis=0) + W[:3, 3]
    normal = -W[:3, 2]
    T_world_arm = planar_pose(PARK) @ mm.T_base_arm
    if rendered and renderer is None:
        renderer = Renderer(default_scene())
    qs: list[Array] = []
    uvs: list[Array] = []
    Cs: list[Array] = []

    def take(T_arm_cam: Array) -> bool:
        """Add the view from camera pose T_arm_cam when the arm reaches it and the board is
        seen whole; return whether it was added."""
        sols = mm.arm.ik_analytic(T_arm_cam @ invert_pose(X), include_singular=False)
        if not sols:
            return False
        q = min(sols, key=lambda s: float(np.sum((s - mm.arm.home) ** 2)))
        # The camera as the joints put it (fk), identical to T_arm_cam up to rounding.
        T_arm_cam = mm.arm.fk(q) @ X
        C_true = invert_pose(T_arm_cam) @ W
        truth = project_points(
            P, matrix_to_rotvec(C_true[:3, :3]), C_true[:3, 3], EYE_K, EYE_DIST
        ).points
        if np.any(truth < 20) or np.any(truth[:, 0] > EYE_SIZE[0] - 21):
            return False
        if np.any(truth[:, 1] > EYE_SIZE[1] - 21):
            return False
        if rendered:
            assert renderer is not None
            cam = eye_camera(T_world_arm @ T_arm_cam)
            frame = renderer.render_board(
                cam, BOARD, T_world_board, rng=rng, noise=SensorNoise() if noise is None else noise
            )
            try:
                uv = find_chessboard(frame.image, BOARD.inner_corners).corners
            except PatternNotFound:
                return False
            if sigma_px > 0:
                uv = uv + rng.normal(0.0, sigma_px, uv.shape)
        else:
            uv = truth + rng.normal(0.0, sigma_px, truth.shape)
        est = estimate_plane_pose(P, uv, cal.K, cal.dist)
        C = np.eye(4)
        C[:3, :3], C[:3, 3] = est.R, est.t
        qs.append(q)
        uvs.append(uv)
        Cs.append(C)
        return True

    attempts = 0
    while len(qs) < views:
        attempts += 1
        if attempts > 200 * views:
            raise InvalidInput("could not find reachable views of the board; check the scene")
        if not take(_look_pose(rng, centre, normal)) or len(qs) > 1 or translations == 0:
            continue
        # The first group: the first view's camera translated along its x, y, z axes in turn,
        # its orientation kept; a first view the arm cannot translate so is drawn again.
        first = mm.arm.fk(qs[0]) @ X
        for k in range(translations):
            for _ in range(30):
                T = first.copy()
                step = rng.choice((-1.0, 1.0)) * rng.uniform(*TRANSLATION_M)
                T[:3, 3] += step * first[:3, k % 3]
                if take(T):
                    break
            else:
                del qs[:], uvs[:], Cs[:]
                break
    q_arr = np.array(qs)
    return HandEyeViews(
        q=q_arr,
        T_base_ee=mm.arm.fk(q_arr),
        T_cam_target=np.array(Cs),
        object_points=P,
        image_points=np.array(uvs),
        K=cal.K.copy(),
        dist=cal.dist.copy(),
        source="rendered" if rendered else "projected",
        intrinsics_from=cal.source,
        translations=translations,
        true_X=X.copy(),
        true_T_base_target=W,
    )


def eye_camera_intrinsics(rng: np.random.Generator) -> RenderedCalibration:
    """Return the eye-in-hand camera's intrinsics as its owner gets them: Zhang from rendered
    chessboard views through its lens (core.sim.intrinsics)."""
    w, h = EYE_SIZE
    return calibrate_from_board_views(
        LandmarkCamera(EYE_K, EYE_DIST, w, h), rng, noise=INTRINSICS_NOISE
    )


def eye_camera(T_world_cam: Array) -> CeilingCamera:
    """Return the eye-in-hand camera at a world pose as a renderable camera."""
    return camera_at("eye_in_hand", EYE_K, EYE_DIST, EYE_SIZE, T_world_cam)
