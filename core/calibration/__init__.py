"""Camera calibration from planes: Zhang, single view, pose, placement from floor points,
pattern detection, interchange."""

from core.calibration.detect import (
    CharucoSpec,
    Chessboard,
    CircleGrid,
    PatternDetection,
    board_object_points,
    find_charuco,
    find_chessboard,
    find_chessboard_on_background,
    find_circle_grid,
)
from core.calibration.io import (
    CalibrationRecord,
    from_opencv_json,
    from_opencv_yaml,
    from_ros_yaml,
    to_opencv_json,
    to_opencv_yaml,
    to_ros_yaml,
)
from core.calibration.placement import CameraPlacement, place_camera
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
    "CalibrationRecord",
    "CameraCalibration",
    "CameraPlacement",
    "CharucoSpec",
    "Chessboard",
    "CircleGrid",
    "PatternDetection",
    "PoseEstimate",
    "SingleViewCalibration",
    "board_object_points",
    "calibrate_camera",
    "calibrate_single_view",
    "estimate_plane_pose",
    "find_charuco",
    "find_chessboard",
    "find_chessboard_on_background",
    "find_circle_grid",
    "focal_from_homography",
    "from_opencv_json",
    "from_opencv_yaml",
    "from_ros_yaml",
    "intrinsics_from_homographies",
    "place_camera",
    "plane_points",
    "pose_from_homography",
    "to_opencv_json",
    "to_opencv_yaml",
    "to_ros_yaml",
]
