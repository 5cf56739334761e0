"""Calibration jobs: decode inputs, call core.calibration, shape the result for storage."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from core.calibration.detect import Chessboard, board_object_points, find_chessboard
from core.calibration.io import CalibrationRecord, to_opencv_yaml, to_ros_yaml
from core.calibration.zhang import CameraCalibration, calibrate_camera
from core.errors import PatternNotFound


def decode_image(data: bytes, max_pixels: int) -> np.ndarray | None:
    """Return the decoded image (grey or BGR uint8), None when `data` is not an image OpenCV
    can read or holds more than `max_pixels` pixels."""
    if not data:
        return None
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.ndim not in (2, 3) or image.shape[0] * image.shape[1] > max_pixels:
        return None
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image


def _result(calibration: CameraCalibration, views_used: list[int] | None) -> dict[str, Any]:
    return {
        "K": np.asarray(calibration.K, dtype=float).tolist(),
        "dist": np.asarray(calibration.dist, dtype=float).ravel().tolist(),
        "rms": float(calibration.rms),
        "std_intrinsics": {k: float(v) for k, v in calibration.std_intrinsics.items()},
        "per_view_rms": np.asarray(calibration.per_view_rms, dtype=float).ravel().tolist(),
        "image_size": [int(v) for v in calibration.image_size],
        "views_used": views_used,
    }


def calibrate_from_correspondences(inputs: dict[str, Any], options: dict[str, Any]) -> dict:
    """Return the stored result of Zhang's calibration on inline correspondences."""
    calibration = calibrate_camera(
        [np.asarray(v, dtype=float) for v in inputs["object_points"]],
        [np.asarray(v, dtype=float) for v in inputs["image_points"]],
        tuple(inputs["image_size"]),
        skew=bool(options.get("skew", False)),
        distortion=str(options.get("distortion", "k1k2p1p2")),
    )
    return _result(calibration, None)


def calibrate_from_images(
    images: Sequence[bytes], inputs: dict[str, Any], options: dict[str, Any]
) -> dict:
    """Return the stored result of Zhang's calibration on photos of a chessboard; images where
    the board is not found are skipped (their indices are missing from views_used)."""
    cols, rows = inputs["chessboard"]
    model = board_object_points_for(cols, rows, float(inputs["square_m"]))
    object_points, image_points, used = [], [], []
    for index, data in enumerate(images):
        image = decode_image(data, max_pixels=2**31)
        if image is None:
            continue
        try:
            detection = find_chessboard(image, (cols, rows))
        except (PatternNotFound, cv2.error):
            # OpenCV's detectors assert on images too small for their windows: not found either.
            continue
        object_points.append(model[detection.ids])
        image_points.append(detection.corners)
        used.append(index)
    if not used:
        raise PatternNotFound(
            f"no {cols}x{rows} chessboard (inner corners) found in any of the {len(images)} "
            "images; check the pattern size (inner corners, not squares) and the photos"
        )
    calibration = calibrate_camera(
        object_points,
        image_points,
        tuple(inputs["image_size"]),
        skew=bool(options.get("skew", False)),
        distortion=str(options.get("distortion", "k1k2p1p2")),
    )
    return _result(calibration, used)


def calibrate_network(inputs: dict[str, Any], options: dict[str, Any]) -> dict:
    """Return the stored result of calibrating the twin's cameras by driving the robot's
    marker (server.services.twin.network_calibration_drive), each camera named by its
    registry id too."""
    from core.sim import default_scene
    from server.services.twin import network_calibration_drive

    result = network_calibration_drive(
        default_scene(), int(options.get("seed", 0)), spacing=float(options.get("spacing", 0.3))
    )
    ids = inputs.get("cameras", {})
    for camera in result["cameras"]:
        camera["camera_id"] = ids.get(camera["name"])
    return result


def board_object_points_for(cols: int, rows: int, square_m: float) -> np.ndarray:
    """Return the (cols * rows, 3) model points of a chessboard of inner corners, metres."""
    return board_object_points(Chessboard(cols, rows), square_m)


def calibration_yaml(
    K: list[list[float]],
    dist: list[float],
    image_size: tuple[int, int],
    fmt: str,
    *,
    camera_name: str,
    rms: float | None = None,
) -> str:
    """Return a calibration as OpenCV FileStorage YAML ("opencv") or ROS camera_info YAML
    ("ros"), written by core.calibration.io."""
    record = CalibrationRecord(
        K=np.asarray(K, dtype=float),
        dist=np.asarray(dist, dtype=float),
        image_size=image_size,
        rms=rms,
        camera_name=camera_name,
    )
    return to_ros_yaml(record) if fmt == "ros" else to_opencv_yaml(record)
