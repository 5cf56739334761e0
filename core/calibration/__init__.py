"""Camera calibration from planes: Zhang, single view, pose, pattern detection, interchange."""

from core.calibration.pose import (
    PoseEstimate,
    estimate_plane_pose,
    plane_points,
    pose_from_homography,
)
from core.calibration.single_view import (
    SingleViewCalibration,
    calibrate_single_view,
    focal_from_homography,
)
from core.calibration.zhang import (
    DISTORTION_MODELS,
    CameraCalibration,
    calibrate_camera,
    intrinsics_from_homographies,
)

__all__ = [
    "DISTORTION_MODELS",
    "CameraCalibration",
    "PoseEstimate",
    "SingleViewCalibration",
    "calibrate_camera",
    "calibrate_single_view",
    "estimate_plane_pose",
    "focal_from_homography",
    "intrinsics_from_homographies",
    "plane_points",
    "pose_from_homography",
]
