"""Calibration interchange: exact round trips, and OpenCV's own FileStorage as the reference."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

import core.calibration.io as calibration_io
from core.errors import InvalidInput

K = np.array([[832.5, 0.204494, 303.959], [0.0, 832.53, 206.585], [0.0, 0.0, 1.0]])
# Awkward values on purpose: tiny, huge and negative ones, and 1/3 that needs all 17 digits.
DIST = np.array([-0.228601, 0.190353, 1e-05, -3.0e-17, 1.0 / 3.0])


def record(**kw: object) -> calibration_io.CalibrationRecord:
    args: dict[str, object] = {
        "K": K,
        "dist": DIST,
        "image_size": (640, 480),
        "rms": 0.336,
        "camera_name": 'ceiling "north" #1, Küche',
    }
    args.update(kw)
    return calibration_io.CalibrationRecord(**args)  # type: ignore[arg-type]


def assert_same(a: calibration_io.CalibrationRecord, b: calibration_io.CalibrationRecord) -> None:
    # Exact: the writers use the shortest text that reads back as the same double.
    assert np.array_equal(a.K, b.K)
    assert np.array_equal(a.dist, b.dist)
    assert a.image_size == b.image_size
    assert a.camera_name == b.camera_name


@pytest.mark.parametrize(
    ("write", "read"),
    [
        (calibration_io.to_opencv_yaml, calibration_io.from_opencv_yaml),
        (calibration_io.to_opencv_json, calibration_io.from_opencv_json),
    ],
    ids=["yaml", "json"],
)
@pytest.mark.parametrize("n_dist", [4, 5, 8, 14])
def test_opencv_round_trip_is_exact(write, read, n_dist: int) -> None:
    dist = np.resize(DIST, n_dist)
    r = record(dist=dist)
    back = read(write(r))
    assert_same(r, back)
    assert back.rms == r.rms


def test_ros_round_trip_is_exact_and_keeps_R_and_P() -> None:
    R = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
    P = np.array([[800.0, 0.0, 300.0, -48.0], [0.0, 800.0, 200.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    r = record(rectification=R, projection=P)
    back = calibration_io.from_ros_yaml(calibration_io.to_ros_yaml(r))
    assert_same(r, back)
    assert np.array_equal(back.R, R)
    assert np.array_equal(back.P, P)
    assert back.rms is None  # camera_info has no field for it


def test_ros_defaults_and_distortion_models() -> None:
    text = calibration_io.to_ros_yaml(record(dist=DIST[:4]))
    assert "distortion_model: plumb_bob" in text
    back = calibration_io.from_ros_yaml(text)
    assert np.array_equal(back.dist, [*DIST[:4], 0.0])  # plumb_bob holds 5: k3 = 0 added
    assert np.array_equal(back.R, np.eye(3))
    assert np.array_equal(back.P, np.hstack([K, np.zeros((3, 1))]))
    assert "distortion_model: rational_polynomial" in calibration_io.to_ros_yaml(
        record(dist=np.resize(DIST, 8))
    )
    with pytest.raises(InvalidInput, match="no distortion model for 14"):
        calibration_io.to_ros_yaml(record(dist=np.resize(DIST, 14)))


def test_reads_a_ros_camera_info_file() -> None:
    # As camera_calibration_parsers writes it (values from a ROS tutorial), with ROS's spacing.
    text = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [ 635.96179,    0.     ,  329.51992,
            0.     ,  633.46448,  233.70566,
            0.     ,    0.     ,    1.     ]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.170521, -0.357249, -0.004223, 0.007101, 0.000000]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1., 0., 0., 0., 1., 0., 0., 0., 1.]
projection_matrix:
  rows: 3
  cols: 4
  data: [650.12, 0., 333.41, 0., 0., 651.5, 232.6, 0., 0., 0., 1., 0.]
"""
    r = calibration_io.from_ros_yaml(text)
    assert r.camera_name == "narrow_stereo"
    assert r.image_size == (640, 480)
    assert r.K[0, 0] == 635.96179 and r.K[1, 2] == 233.70566
    assert np.array_equal(r.dist, [0.170521, -0.357249, -0.004223, 0.007101, 0.0])
    assert r.P[0, 0] == 650.12


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_cv2_filestorage_reads_what_we_write(tmp_path: Path, suffix: str) -> None:
    r = record()
    path = tmp_path / f"camera{suffix}"
    path.write_text(
        calibration_io.to_opencv_yaml(r) if suffix == ".yaml" else calibration_io.to_opencv_json(r)
    )
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        assert fs.isOpened()
        assert np.array_equal(fs.getNode("camera_matrix").mat(), K)
        assert np.array_equal(fs.getNode("distortion_coefficients").mat().ravel(), DIST)
        assert fs.getNode("image_width").real() == 640
        assert fs.getNode("image_height").real() == 480
        assert fs.getNode("avg_reprojection_error").real() == 0.336
        assert fs.getNode("camera_name").string() == r.camera_name
    finally:
        fs.release()


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_we_read_what_cv2_filestorage_writes(tmp_path: Path, suffix: str, dtype: type) -> None:
    path = tmp_path / f"camera{suffix}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("calibration_time", "Sat Nov 21 2026")
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", K.astype(dtype))
    fs.write("distortion_coefficients", DIST.astype(dtype).reshape(1, 5))
    fs.write("avg_reprojection_error", 0.336)
    fs.write("extrinsic_parameters", np.arange(12.0).reshape(2, 6))
    fs.release()
    text = path.read_text()
    r = (
        calibration_io.from_opencv_yaml(text)
        if suffix == ".yaml"
        else calibration_io.from_opencv_json(text)
    )
    # OpenCV writes enough digits to give back the same value in the matrix's own precision.
    assert np.array_equal(r.K.astype(dtype), K.astype(dtype))
    assert np.array_equal(r.dist.astype(dtype), DIST.astype(dtype))
    assert r.image_size == (640, 480)
    assert r.rms == 0.336


def test_reads_other_opencv_key_names() -> None:
    # OpenCV's interactive-calibration tool writes these names.
    text = """%YAML:1.0
---
cameraResolution: [ 1280, 720 ]
cameraMatrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1000., 0., 640., 0., 1000., 360., 0., 0., 1. ]
dist_coeffs: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -1e-01, 1e-02, 0., 0., 0. ]
"""
    r = calibration_io.from_opencv_yaml(text)
    assert r.image_size == (1280, 720)
    assert r.K[0, 2] == 640.0
    assert np.array_equal(r.dist, [-0.1, 0.01, 0.0, 0.0, 0.0])  # "1e-01" is text to YAML 1.1


VALID_YAML = calibration_io.to_opencv_yaml(record())


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("", "empty"),
        ("%YAML:1.0\n---\ncamera_matrix: [1, 2\n", "not valid OpenCV YAML"),
        ("%YAML:1.0\n---\n- a list\n", "mapping"),
        (VALID_YAML.replace("camera_matrix", "cam"), "no camera_matrix"),
        (VALID_YAML.replace("distortion_coefficients", "dist"), "no distortion_coefficients"),
        (VALID_YAML.replace("image_width: 640\n", ""), "image_width"),
        (VALID_YAML.replace("image_width: 640", "image_width: wide"), "image_width"),
        (VALID_YAML.replace("rows: 3", "rows: 4", 1), "rows x cols"),
        (VALID_YAML.replace("303.959", "zero"), "camera_matrix: data must hold only numbers"),
        (
            VALID_YAML.replace("rows: 5", "rows: 6").replace("0.3333333333333333", "1/3, 1.0"),
            "distortion_coefficients: data must hold only numbers",
        ),
        (
            VALID_YAML.replace("rows: 5", "rows: 6").replace("0.3333333333333333", "0.3, 1.0"),
            "4, 5, 8, 12 or 14",
        ),
        (VALID_YAML.replace("rows: 3", "rows: 4", 1), "camera_matrix: rows x cols"),
        (VALID_YAML.replace("832.5,", ".nan,"), "NaN"),
        (VALID_YAML.replace("0.0, 832.53", "5.0, 832.53"), "upper triangular"),
    ],
)
def test_malformed_opencv_yaml_raises_with_reason(text: str, reason: str) -> None:
    with pytest.raises(InvalidInput, match=reason):
        calibration_io.from_opencv_yaml(text)


VALID_ROS = calibration_io.to_ros_yaml(record())


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("{ not: [closed", "not valid ROS"),
        ("42\n", "mapping"),
        (VALID_ROS.replace("plumb_bob", "equidistant"), "unsupported distortion_model"),
        (VALID_ROS.replace("plumb_bob", "rational_polynomial"), "has 8 coefficients, got 5"),
        (VALID_ROS.replace("  rows: 3\n  cols: 4", "  rows: 4\n  cols: 3"), "expected 3 x 4"),
        (VALID_ROS.replace("camera_matrix:", "K:"), "camera_matrix must be"),
        (VALID_ROS.replace("image_height: 480", "image_height: 480.5"), "image_height"),
    ],
)
def test_malformed_ros_yaml_raises_with_reason(text: str, reason: str) -> None:
    with pytest.raises(InvalidInput, match=reason):
        calibration_io.from_ros_yaml(text)


def test_malformed_json_raises_with_reason() -> None:
    with pytest.raises(InvalidInput, match="not valid JSON"):
        calibration_io.from_opencv_json("{")
    with pytest.raises(InvalidInput, match="opencv-matrix"):
        calibration_io.from_opencv_json('{"camera_matrix": 3, "distortion_coefficients": 4}')


@pytest.mark.parametrize(
    ("kw", "reason"),
    [
        ({"K": np.eye(2)}, "shape"),
        ({"K": -K}, "fx, fy > 0"),
        ({"dist": np.zeros(6)}, "4, 5, 8, 12 or 14"),
        ({"image_size": (640,)}, "width, height"),
        ({"image_size": (0, 480)}, "positive"),
        ({"rms": float("nan")}, "rms"),
        ({"rms": "small"}, "rms must be a number"),
        ({"projection": np.eye(3)}, "shape"),
    ],
)
def test_record_validates(kw: dict[str, object], reason: str) -> None:
    with pytest.raises(InvalidInput, match=reason):
        record(**kw)
