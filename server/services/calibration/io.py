"""Calibration data in and out: images decoded for OpenCV, calibration files written (OpenCV
and ROS YAML by core.calibration.io), a chessboard's model points."""

from __future__ import annotations

import cv2
import numpy as np

from core.calibration.detect import Chessboard, board_object_points
from core.calibration.io import CalibrationRecord, to_opencv_yaml, to_ros_yaml


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
