"""Pattern detection on rendered photos, against the exact projections of the model points.

The photos (conftest.py) are 640x480, squares 37-45 px, optical blur sigma 0.6 px, sensor noise
sigma 2 grey levels on a contrast of 190, barrel distortion of ~36 px in the corners. For a
saddle-point estimator the corner standard deviation is about sigma_noise / (contrast * sqrt(n))
times a window factor of a few, n ~ 100 edge pixels: a few hundredths of a pixel, and what we
measure is 0.04-0.05 px RMS. Tolerances below are about twice that.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import cv2
import numpy as np
import pytest

from core.calibration.detect import (
    CharucoSpec,
    Chessboard,
    CircleGrid,
    as_grey_u8,
    board_object_points,
    find_charuco,
    find_chessboard,
    find_circle_grid,
)
from core.calibration.zhang import calibrate_camera
from core.errors import InvalidInput, PatternNotFound


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


# --- chessboard --------------------------------------------------------------------------------


def test_chessboard_corners_match_the_true_projections(chessboard_views: list[Any]) -> None:
    errors = []
    for v in chessboard_views:
        d = find_chessboard(v.image, (9, 6))
        assert d.corners.shape == (54, 2) and d.corners.dtype == np.float64
        assert np.array_equal(d.ids, np.arange(54))
        # Same order as the model (first corner next to the black outer square), so no flip.
        assert rms(d.corners, v.true_points) < 0.08
        errors.append(d.corners - v.true_points)
    e = np.concatenate(errors)
    # No systematic shift: a half-pixel convention slip would show as 0.5 px here.
    assert np.all(np.abs(e.mean(axis=0)) < 0.01)
    assert rms(e, np.zeros_like(e)) < 0.06


def test_chessboard_order_is_fixed_by_the_black_square(photos: ModuleType) -> None:
    # The board turned upside down in the image: detectors then start from the other end.
    rng = np.random.default_rng(11)
    tex = photos.chessboard_texture(9, 6, 0.025)
    model = photos.chessboard_model(9, 6, 0.025)
    (rvec, tvec), *_ = photos.board_poses(np.array([0.1, 0.0625, 0.0]), 0.42, 1)
    R = cv2.Rodrigues(rvec)[0] @ cv2.Rodrigues(np.array([0.0, 0.0, np.pi]))[0]
    t = tvec + cv2.Rodrigues(rvec)[0] @ np.array([0.1, 0.0625, 0.0]) - R @ [0.1, 0.0625, 0.0]
    v = photos.render_view(tex, model, cv2.Rodrigues(R)[0].ravel(), t, rng)
    d = find_chessboard(v.image, (9, 6))
    assert rms(d.corners, v.true_points) < 0.1


def test_image_types_give_the_same_corners(chessboard_views: list[Any]) -> None:
    grey = chessboard_views[0].image
    ref = find_chessboard(grey, (9, 6)).corners
    variants = [
        cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR),
        cv2.cvtColor(grey, cv2.COLOR_GRAY2BGRA),
        grey[:, :, None],
        grey.astype(np.uint16) * 257,
        grey / 255.0,
    ]
    for img in variants:
        assert np.array_equal(as_grey_u8(img), grey)
        assert np.allclose(find_chessboard(img, (9, 6)).corners, ref, atol=1e-9)


def test_calibration_from_detected_corners_recovers_the_camera(
    photos: ModuleType, chessboard_views: list[Any]
) -> None:
    dets = [find_chessboard(v.image, (9, 6)) for v in chessboard_views]
    cal = calibrate_camera(
        [d.object_points(0.025) for d in dets], [d.corners for d in dets], (640, 480)
    )
    std = cal.std_intrinsics
    # Detection noise ~0.05 px over 6 x 54 points: fx, fy known to ~0.04 %, cx, cy to ~0.4 px
    # (the reported standard deviations). Errors must be within 4 of them and fx, fy within 0.2 %.
    assert cal.rms < 0.06
    for name, i, j in (("fx", 0, 0), ("fy", 1, 1), ("cx", 0, 2), ("cy", 1, 2)):
        assert abs(cal.K[i, j] - photos.TRUE_K[i, j]) < 4.0 * std[name], name
    assert abs(cal.K[0, 0] / photos.TRUE_K[0, 0] - 1.0) < 0.002
    assert abs(cal.K[1, 1] / photos.TRUE_K[1, 1] - 1.0) < 0.002
    # k1 is known to ~0.003 (its reported standard deviation): 0.01 is over 3 of them.
    assert abs(cal.dist[0] - photos.TRUE_DIST[0]) < 0.01
    # Poses: the board 0.42 m away, recovered to a millimetre.
    for d_t, pose in zip(
        cal.tvecs, photos.board_poses(np.array([0.1, 0.0625, 0.0]), 0.42), strict=True
    ):
        assert np.allclose(d_t, pose[1], atol=1e-3)


def test_chessboard_not_found() -> None:
    blank = np.full((480, 640), 200, np.uint8)
    with pytest.raises(PatternNotFound, match="9x6 chessboard"):
        find_chessboard(blank, (9, 6))


def test_wrong_chessboard_size_not_found(chessboard_views: list[Any]) -> None:
    with pytest.raises(PatternNotFound):
        find_chessboard(chessboard_views[0].image, (8, 6))


@pytest.mark.parametrize(
    ("image", "reason"),
    [
        (np.zeros(100, np.uint8), "shape"),
        (np.zeros((100, 100, 2), np.uint8), "shape"),
        (np.zeros((4, 100), np.uint8), "too small"),
        (np.zeros((100, 100), bool), "dtype"),
        (np.full((100, 100), 255.0), r"\[0, 1\]"),
        (np.full((100, 100), np.nan), "NaN"),
        ("photo.png", "shape"),
    ],
)
def test_bad_images_raise_invalid_input(image: object, reason: str) -> None:
    with pytest.raises(InvalidInput, match=reason):
        find_chessboard(image, (9, 6))  # type: ignore[arg-type]


@pytest.mark.parametrize("size", [(1, 6), (9.5, 6), (9,), "9x6", (True, 6)])
def test_bad_pattern_size_raises_invalid_input(size: object) -> None:
    with pytest.raises(InvalidInput, match="cols, rows"):
        find_chessboard(np.zeros((100, 100), np.uint8), size)  # type: ignore[arg-type]


# --- model points ------------------------------------------------------------------------------


def test_board_object_points_layouts() -> None:
    cb = board_object_points(Chessboard(9, 6), 0.025)
    assert cb.shape == (54, 3)
    assert np.allclose(
        cb[[0, 1, 9, 53]], [[0, 0, 0], [0.025, 0, 0], [0, 0.025, 0], [0.2, 0.125, 0]]
    )
    # OpenCV's calibration sample: asymmetric centre (j, i) at ((2j + i % 2) s, i s, 0).
    ac = board_object_points(CircleGrid(4, 11, symmetric=False), 0.02)
    ref = [((2 * j + i % 2) * 0.02, i * 0.02, 0.0) for i in range(11) for j in range(4)]
    assert np.allclose(ac, ref)
    spec = CharucoSpec(8, 6, 0.75, "DICT_5X5_100")
    board = cv2.aruco.CharucoBoard(
        (8, 6), 0.03, 0.0225, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
    )
    # OpenCV stores them as float32.
    assert np.allclose(board_object_points(spec, 0.03), board.getChessboardCorners(), atol=1e-7)


@pytest.mark.parametrize("square", [0.0, -0.02, float("nan")])
def test_bad_square_size(square: float) -> None:
    with pytest.raises(InvalidInput, match="square_size"):
        board_object_points(Chessboard(9, 6), square)


# --- circle grids ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("pattern", "spacing", "tol"),
    [
        # The centroid of a circle's image is not the image of its centre: for these 13 px
        # circles seen at up to 35 degrees the bias is 0.1-0.14 px (measured), hence 0.2 px.
        (CircleGrid(7, 5), 0.03, 0.2),
        # Smaller circles (r = 9 px): bias and tolerance scale with r^2.
        (CircleGrid(4, 11, symmetric=False), 0.02, 0.1),
    ],
    ids=["symmetric", "asymmetric"],
)
def test_circle_grid_centres_match_the_true_projections(
    photos: ModuleType, pattern: CircleGrid, spacing: float, tol: float
) -> None:
    rng = np.random.default_rng(5)
    tex = photos.circle_grid_texture(pattern.cols, pattern.rows, spacing, pattern.symmetric)
    model = board_object_points(pattern, spacing)
    for rvec, tvec in photos.board_poses(model.mean(axis=0), 0.42, 3):
        v = photos.render_view(tex, model, rvec, tvec, rng)
        d = find_circle_grid(v.image, (pattern.cols, pattern.rows), pattern.symmetric)
        assert d.pattern == pattern
        assert rms(d.corners, v.true_points) < tol
        assert np.array_equal(d.object_points(spacing), model)


def test_circle_grid_not_found(chessboard_views: list[Any]) -> None:
    with pytest.raises(PatternNotFound, match="symmetric 7x5 circle grid"):
        find_circle_grid(chessboard_views[0].image, (7, 5))


# --- ChArUco -----------------------------------------------------------------------------------

CHARUCO = CharucoSpec(8, 6, 0.75, "DICT_5X5_100")


@pytest.fixture(scope="module")
def charuco_views(photos: ModuleType) -> list[Any]:
    board = cv2.aruco.CharucoBoard(
        (8, 6), 0.03, 0.0225, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
    )
    rng = np.random.default_rng(9)
    tex = photos.charuco_texture(board)
    model = board_object_points(CHARUCO, 0.03)
    poses = photos.board_poses(np.array([0.12, 0.09, 0.0]), 0.42, 3)
    return [photos.render_view(tex, model, rv, tv, rng) for rv, tv in poses]


def test_charuco_corners_match_the_true_projections(charuco_views: list[Any]) -> None:
    for v in charuco_views:
        d = find_charuco(v.image, CHARUCO)
        assert np.array_equal(np.sort(d.ids), np.arange(35))  # 7 x 5 inner corners, all seen
        # Measured 0.06-0.07 px (the markers' bits limit the refinement window).
        assert rms(d.corners, v.true_points[d.ids]) < 0.1


def test_charuco_partial_view_keeps_the_ids(charuco_views: list[Any]) -> None:
    img = charuco_views[0].image.copy()
    img[:, 320:] = 128  # the right half of the photo covered
    d = find_charuco(img, CHARUCO)
    assert 6 <= len(d.ids) < 35
    assert np.all(d.corners[:, 0] < 320)
    assert rms(d.corners, charuco_views[0].true_points[d.ids]) < 0.1
    assert np.array_equal(d.object_points(0.03), board_object_points(CHARUCO, 0.03)[d.ids])


def test_charuco_wrong_dictionary_not_found(charuco_views: list[Any]) -> None:
    with pytest.raises(PatternNotFound, match="0 corners found"):
        find_charuco(charuco_views[0].image, CharucoSpec(8, 6, 0.75, "DICT_4X4_50"))


@pytest.mark.parametrize(
    ("spec", "reason"),
    [
        (CharucoSpec(8, 6, 0.75, "DICT_NOPE"), "unknown ArUco dictionary"),
        (CharucoSpec(8, 6, 1.2), "marker_ratio"),
        (CharucoSpec(20, 20, 0.75, "DICT_4X4_50"), "needs 200 markers"),
    ],
)
def test_bad_charuco_spec_raises_invalid_input(spec: CharucoSpec, reason: str) -> None:
    with pytest.raises(InvalidInput, match=reason):
        find_charuco(np.zeros((100, 100), np.uint8), spec)


@pytest.mark.parametrize("shape", [(8, 8), (20, 30), (30, 20, 3)])
def test_images_too_small_for_the_pattern_are_not_found_with_a_reason(shape):
    # OpenCV asserts (cv2.error) on images smaller than its filter windows; the detectors must
    # answer with the typed error instead.
    image = np.full(shape, 128, np.uint8)
    with pytest.raises(PatternNotFound, match="too small"):
        find_chessboard(image, (9, 6))
    with pytest.raises(PatternNotFound, match="too small"):
        find_circle_grid(image, (4, 11), symmetric=False)
    with pytest.raises(PatternNotFound, match="too small"):
        find_charuco(image, CharucoSpec(8, 6))
