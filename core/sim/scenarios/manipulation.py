"""Manipulation scenarios of the twin: the eye-in-hand camera's hand-eye calibration and the
fetch.

* `hand_eye`: every method of core.manipulation.calibrate_hand_eye and the reprojection
  refinement on the same views (core.sim.eye_in_hand.hand_eye_views, the camera's intrinsics
  from its own calibration), errors against the twin's truth.
* `grasp`: randomised fetches of the marked box on the dining table by the switching grasp
  controller (core.sim.fetch: the box with a printed chessboard on its top, not spec 04's
  object mark with its blue frame, `GRASP_TARGET`, stated in the record), every image
  rendered by the twin and the mark's corners detected in it, plus 0.5 px noise.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.geometry.camera import project_points
from core.geometry.poses import invert_pose
from core.geometry.rotations import matrix_to_rotvec
from core.manipulation import (
    METHODS,
    default_manipulator,
    pose_error,
)
from core.sim.eye_in_hand import (
    EYE_DIST,
    EYE_K,
    HandEyeMethodError,
    hand_eye_error,
    hand_eye_views,
)
from core.sim.fetch import (
    GRASP_TARGET,
    GraspEpisode,
    fetch_episodes,
    prepare_fetch,
)
from core.sim.intrinsics import focal_error_pct
from core.sim.render import Renderer
from core.sim.scene import Scene, default_scene

Array = NDArray[np.float64]

__all__ = ["GraspResult", "HandEyeMethodError", "HandEyeResult", "grasp", "hand_eye"]


@dataclass(frozen=True)
class HandEyeResult:
    """Metrics of `hand-eye`: the views (`translations` of them pure translations of the first,
    the two-group method's first group; `source`: corners detected in rendered images, or true
    projections), where the camera's intrinsics came from (`intrinsics_from`: its own Zhang
    calibration) and their focal error against the true lens (%, scoring only), the Gaussian
    pixel noise `sigma_px` added to them, the measured pixel noise of the final pixels against
    the true corners (RMS per axis), every linear method's errors and the reprojection
    refinement's (started from Park-Martin), with the refinement's RMS reprojection error in
    pixels."""

    scenario: str
    seed: int
    views: int
    translations: int
    source: str
    intrinsics_from: str
    focal_error_pct: float
    sigma_px: float
    measured_sigma_px: float
    methods: tuple[HandEyeMethodError, ...]
    refined: HandEyeMethodError
    refined_rms_px: float

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


def hand_eye(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    views: int = 15,
    rendered: bool = True,
    sigma_px: float = 0.5,
) -> HandEyeResult:
    """Return the `hand-eye` scenario's metrics: `views` views of the table's chessboard from
    the eye-in-hand camera (rendered and detected by default; `rendered=False` projects the
    true corners), `sigma_px` Gaussian noise added to the pixels, calibrated by every method
    and refined."""
    rng = np.random.default_rng(seed)
    renderer = Renderer(scene if scene is not None else default_scene()) if rendered else None
    v = hand_eye_views(rng, views=views, sigma_px=sigma_px, rendered=rendered, renderer=renderer)
    # Scoring only: the detections against the true projections.
    C_true = invert_pose(v.T_base_ee @ v.true_X) @ v.true_T_base_target
    truth = np.stack(
        [
            project_points(
                v.object_points, matrix_to_rotvec(c[:3, :3]), c[:3, 3], EYE_K, EYE_DIST
            ).points
            for c in C_true
        ]
    )
    measured = float(np.sqrt(np.mean((v.image_points - truth) ** 2)))
    rows = []
    for m in METHODS:
        r = v.calibrate(m)
        rows.append(hand_eye_error(m, r.X, v.true_X, r.rotation_std_deg, r.translation_std_m))
    ref = v.calibrate("park", refine=True)
    return HandEyeResult(
        scenario="hand-eye",
        seed=seed,
        views=views,
        translations=v.translations,
        source=v.source,
        intrinsics_from=v.intrinsics_from,
        focal_error_pct=focal_error_pct(v.K, EYE_K),
        sigma_px=sigma_px,
        measured_sigma_px=measured,
        methods=tuple(rows),
        refined=hand_eye_error(
            "park+refine", ref.X, v.true_X, ref.rotation_std_deg, ref.translation_std_m
        ),
        refined_rms_px=float(ref.rms_px if ref.rms_px is not None else math.nan),
    )


# --------------------------------------------------------------------------------------------
# Grasping


@dataclass(frozen=True)
class GraspResult:
    """Metrics of `grasp`: episodes, success rate, medians over successes of the final
    end-effector position error (m) and rotation error (deg), median time (s), failure
    reasons with counts, the hand-eye transform's own error (it was calibrated first, refined,
    from 15 views), where the eye-in-hand camera's intrinsics came from (`intrinsics_from`: its
    own Zhang calibration, done first) and their focal error (%, scoring only), what the fetch
    grasps (`target`, GRASP_TARGET), the images' source ("rendered": the twin's images,
    corners detected; "projected": true projections), the eye-in-hand images taken in all, the
    median gripper opening at closing over successes (mm; the box is 115 mm wide), and every
    episode."""

    scenario: str
    seed: int
    episodes: int
    success_rate: float
    position_error_m: float
    rotation_error_deg: float
    time_s: float
    failures: dict[str, int]
    hand_eye_rotation_error_deg: float
    hand_eye_translation_error_mm: float
    intrinsics_from: str
    focal_error_pct: float
    target: str
    sigma_px: float
    source: str
    frames: int
    gripper_opening_mm: float
    per_episode: tuple[GraspEpisode, ...]

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


def grasp(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    episodes: int = 100,
    sigma_px: float = 0.5,
    rendered: bool = True,
) -> GraspResult:
    """Return the `grasp` scenario's metrics: the eye-in-hand camera is first calibrated
    (15 views, refined), the mark taught once (core.sim.fetch.prepare_fetch), then
    `episodes` randomised fetches of a marked box on the dining table (random placement and
    yaw, a prior 5 cm / 0.15 rad off, a random start in the kitchen corridor) run the
    switching controller with `sigma_px` pixel noise. `rendered` (the default): every image
    is rendered by the twin and its corners detected; otherwise the true projections."""
    rng = np.random.default_rng(seed)
    mm = default_manipulator()
    # The moving camera's static layer is drawn without supersampling: a new one every frame.
    renderer = (
        Renderer(scene if scene is not None else default_scene(), supersample=1)
        if rendered
        else None
    )
    prepared = prepare_fetch(rng, mm, sigma_px=sigma_px, renderer=renderer)
    cal = prepared.intrinsics
    he_dp, he_dr = pose_error(prepared.X, mm.T_ee_camera)
    eps = tuple(fetch_episodes(rng, mm, prepared, episodes, sigma_px=sigma_px, renderer=renderer))
    good = [e for e in eps if e.success]
    failures: dict[str, int] = {}
    for e in eps:
        if not e.success:
            failures[e.reason] = failures.get(e.reason, 0) + 1

    def med(vals: list[float]) -> float:
        return float(np.median(vals)) if vals else math.nan

    return GraspResult(
        scenario="grasp",
        seed=seed,
        episodes=episodes,
        success_rate=len(good) / max(episodes, 1),
        position_error_m=med([e.position_error_mm / 1e3 for e in good]),
        rotation_error_deg=med([e.rotation_error_deg for e in good]),
        time_s=med([e.time_s for e in eps]),
        failures=failures,
        hand_eye_rotation_error_deg=math.degrees(float(he_dr)),
        hand_eye_translation_error_mm=1e3 * float(he_dp),
        intrinsics_from=cal.source,
        focal_error_pct=focal_error_pct(cal.K, EYE_K),
        target=GRASP_TARGET,
        sigma_px=sigma_px,
        source="rendered" if rendered else "projected",
        frames=sum(e.frames for e in eps),
        gripper_opening_mm=med([e.gripper_opening_mm for e in good]),
        per_episode=eps,
    )
