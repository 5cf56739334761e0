"""Named, seeded scenarios of the digital twin, each returning its metrics as a typed record.

* `network-calibration`, `network-calibration-board`: every ceiling camera calibrated by the
  robot's marker or its chessboard (core.sim.scenarios.network).
* `localization`, `localization-images`: the ground estimators against the Cramer-Rao bound
  (core.sim.scenarios.floor_localization).
* `tracking`, `tracking-async`: the one tracker scored by the MOT metrics, on rendered images
  and on unsynchronised cameras' points (core.sim.scenarios.multi_target_tracking); `minutes`
  shortens them.
* `path-following`, `projector-calibration`: the projector drawing a planned path that the
  robot follows by three control laws, and the projector's mount calibrated from spots seen by
  the ceiling cameras (core.sim.scenarios.path_following, projector_calibration).
* `landmark-pose`, `landmark-reading`, `landmark-survey`: object marks and signposts located
  and read by the robot's head camera, reading by PBVS, and the survey that builds the maps
  (core.sim.scenarios.landmark_pose, landmark_reading, landmark_survey).
* `hand-eye`, `grasp`: the eye-in-hand camera's hand-eye calibration by every method and the
  reprojection refinement, and randomised fetches by the switching grasp controller
  (core.sim.scenarios.manipulation).

`run_scenario(name, scene=None, seed=0)` runs one; `SCENARIOS` is the one registry (name ->
function(scene, seed)) and `DESCRIPTIONS` their one-line descriptions; modules that add
scenarios register them in both. Every record has `to_dict()` giving plain JSON-ready values.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from core.errors import InvalidInput
from core.sim.network_drive import MarkerDrive
from core.sim.network_errors import PoseErrors, calibration_errors
from core.sim.scenarios.floor_localization import localization, localization_images
from core.sim.scenarios.landmark_pose import LandmarkPoseResult, landmark_pose
from core.sim.scenarios.landmark_reading import LandmarkReadingResult, landmark_reading
from core.sim.scenarios.landmark_survey import LandmarkSurveyResult, landmark_survey
from core.sim.scenarios.manipulation import grasp, hand_eye
from core.sim.scenarios.multi_target_tracking import TrackingResult, tracking, tracking_async
from core.sim.scenarios.network import (
    accuracy_study,
    board_mounting,
    mount_board,
    network_calibration,
    network_calibration_board,
)
from core.sim.scenarios.path_following import PathFollowingResult, path_following
from core.sim.scenarios.projector_calibration import (
    ProjectorCalibrationResult,
    projector_calibration,
)
from core.sim.scenarios.records import (
    AccuracyRow,
    CameraCalibrationError,
    LocalizationResult,
    NetworkCalibrationResult,
    RejectedCameraReport,
    ScenarioResult,
)
from core.sim.scene import Scene

__all__ = [
    "DESCRIPTIONS",
    "SCENARIOS",
    "AccuracyRow",
    "CameraCalibrationError",
    "LandmarkPoseResult",
    "LandmarkReadingResult",
    "LandmarkSurveyResult",
    "LocalizationResult",
    "MarkerDrive",
    "NetworkCalibrationResult",
    "PathFollowingResult",
    "PoseErrors",
    "ProjectorCalibrationResult",
    "RejectedCameraReport",
    "ScenarioResult",
    "TrackingResult",
    "accuracy_study",
    "board_mounting",
    "calibration_errors",
    "landmark_pose",
    "landmark_reading",
    "landmark_survey",
    "localization",
    "localization_images",
    "mount_board",
    "network_calibration",
    "network_calibration_board",
    "path_following",
    "projector_calibration",
    "run_scenario",
    "tracking",
    "tracking_async",
]

SCENARIOS: dict[str, Callable[..., ScenarioResult]] = {
    "network-calibration": network_calibration,
    "network-calibration-board": network_calibration_board,
    "localization": localization,
    "localization-images": localization_images,
    "tracking": tracking,
    "tracking-async": tracking_async,
    "path-following": path_following,
    "projector-calibration": projector_calibration,
    "landmark-pose": landmark_pose,
    "landmark-reading": landmark_reading,
    "landmark-survey": landmark_survey,
    "hand-eye": hand_eye,
    "grasp": grasp,
}

DESCRIPTIONS: dict[str, str] = {
    "network-calibration": "calibrate every ceiling camera by driving the robot's marker "
    "(intrinsics from a chessboard shown to each camera, poses from the odometry)",
    "network-calibration-board": "calibrate every ceiling camera (with its lens) by driving "
    "the robot's chessboard",
    "localization": "ground estimators vs the Cramer-Rao bound on noisy true projections",
    "localization-images": "ground estimators on the robot marker detected in rendered images",
    "tracking": "the robot and three walkers tracked from rendered images for 30 minutes "
    "(MOTA, IDF1, identity switches)",
    "tracking-async": "three walkers tracked from four unsynchronised cameras' unlabelled "
    "points, with noise, misses and clutter, for 10 minutes",
    "path-following": "a ~10 m living-room tour planned on the floor plan, drawn by the "
    "calibrated projector at 0.3 m/s and followed by the state-feedback, adaptive and "
    "proportional laws (floor camera 15 Hz, 100 ms latency)",
    "projector-calibration": "the projector's mount from 23 commanded spots detected in the "
    "ceiling cameras' images and located with their network calibration",
    "landmark-pose": "object marks and signposts located and read by the robot's head camera "
    "at 0.5-5 m and 0-70 deg, beside zxing-cpp, cv2.QRCodeDetector and an AprilTag (IPPE)",
    "landmark-reading": "a landmark read by position-based visual servoing (head search, "
    "polar pose-regulation law, re-estimated every frame) from 100 random start poses",
    "landmark-survey": "the robot tours the home, reads every landmark it locates (by PBVS "
    "when needed) and builds the semantic and navigation maps on its odometry fused with "
    "signposts and ceiling-camera fixes of its marker",
    "hand-eye": "hand-eye calibration of the eye-in-hand camera: every method and the "
    "reprojection refinement on 15 rendered views of a table chessboard (detected, +0.5 px)",
    "grasp": "100 randomised fetches of a marked box on the dining table by the switching "
    "grasp controller (gaze approach, hysteresis switch, look-then-move)",
}


# Scenarios whose length a caller may set (`minutes`), never their conditions: the simulated
# length of the tracking ones, the drive's of network-calibration.
TIMED = ("tracking", "tracking-async", "network-calibration")


def run_scenario(
    name: str, scene: Scene | None = None, seed: int = 0, *, minutes: float | None = None
) -> ScenarioResult:
    """Return the metrics of the scenario called `name` on `scene` (default home) with `seed`;
    `minutes` sets the simulated length of the timed scenarios (TIMED; for network-calibration
    the longest the calibration drive may last, 5 by default).

    Raises InvalidInput naming the known scenarios when `name` is not one of them, or when
    `minutes` is given to a scenario without a length or is not positive.
    """
    fn = SCENARIOS.get(name)
    if fn is None:
        raise InvalidInput(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")
    if minutes is None:
        return fn(scene, seed)
    if name not in TIMED:
        raise InvalidInput(f"scenario {name!r} has no length to set; timed: {', '.join(TIMED)}")
    if not (math.isfinite(minutes) and minutes > 0):
        raise InvalidInput(f"minutes must be a positive number, got {minutes}")
    return fn(scene, seed, minutes=minutes)
