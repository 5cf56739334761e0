"""Photo-realistic renderings of calibration boards through a known camera with lens distortion.

There are no real photos of our boards in the repository, so the tests make them: a flat board
texture (pattern drawn at 100 px per square) is imaged through a pinhole camera with OpenCV's
radial-tangential distortion, optical blur and sensor noise. The ground truth of every view is the
exact projection of the board's model points by cv2.projectPoints.

Rendering is done by inverse mapping, the way a lens forms an image: for every pixel of the
distorted photo we undistort its coordinates (OpenCV's iteration, run to 1e-12 px), intersect
the ray with the board plane (inverse homography) and sample the texture there (cv2.remap). That
is cv2.warpPerspective composed with the inverse of cv2.initUndistortRectifyMap, done in one
remap so the texture is resampled once. The photo is rendered at 3x resolution and box-filtered
down (pixel-area integration, as a sensor does), which anti-aliases the edges without moving them.

The functions are plain (not fixtures) so that the command-line tests can load this file and
build the same photos; tests here reach them through the `photos` fixture (this module).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

Array = NDArray[np.float64]

IMAGE_SIZE = (640, 480)  # (width, height) px
TRUE_K = np.array([[620.0, 0.0, 322.5], [0.0, 615.0, 236.0], [0.0, 0.0, 1.0]])
# A typical small wide-angle lens: barrel distortion moves the image corners by ~36 px (18 px at
# the middle of the long sides); small decentring.
TRUE_DIST = np.array([-0.21, 0.09, 0.0008, -0.0005, 0.0])

_SUPERSAMPLE = 3  # the photo is rendered at 3x and box-filtered down
_TEX_PX = 100  # texture pixels per board square (per circle spacing for circle grids)
_TEX_MARGIN = 100  # white quiet zone around the pattern in the texture, px


@dataclass(frozen=True)
class Texture:
    """A board texture: grey image and the map from board metres to texture pixels."""

    image: NDArray[np.uint8]  # (H, W) grey
    tex_from_board: Array  # (3, 3): texture px ~ tex_from_board @ (X, Y, 1), X, Y in metres


@dataclass(frozen=True)
class View:
    """One rendered photo and its ground truth."""

    image: NDArray[np.uint8]  # (480, 640) grey
    rvec: Array  # (3,) board-to-camera rotation vector
    tvec: Array  # (3,) board-to-camera translation, metres
    true_points: Array  # (N, 2) exact projection of the model points, px


def _board_to_texture(square: float, offset_px: float) -> Array:
    """Return the (3, 3) map from board metres to texture px (pixel centres at integers).

    A sharp texture edge between pixel columns k-1 and k lies at k - 0.5 under bilinear
    sampling, hence the half-pixel shift.
    """
    s = _TEX_PX / square
    return np.array([[s, 0.0, offset_px - 0.5], [0.0, s, offset_px - 0.5], [0.0, 0.0, 1.0]])


def chessboard_texture(cols: int, rows: int, square: float) -> Texture:
    """Return a chessboard with cols x rows inner corners; model origin at the first inner corner.

    The square at the top-left is black, so boards with one even and one odd corner count are not
    symmetric under a half turn.
    """
    sq_x, sq_y = cols + 1, rows + 1
    ii, jj = np.indices((sq_y * _TEX_PX, sq_x * _TEX_PX))
    black = ((ii // _TEX_PX + jj // _TEX_PX) % 2) == 0
    board = np.where(black, 0, 255).astype(np.uint8)
    tex = np.pad(board, _TEX_MARGIN, constant_values=255)
    return Texture(tex, _board_to_texture(square, _TEX_MARGIN + _TEX_PX))


def circle_grid_texture(cols: int, rows: int, spacing: float, symmetric: bool = True) -> Texture:
    """Return black circles (radius 0.3 spacing) on white at OpenCV's grid positions.

    Symmetric: centre (c, r) at (c, r) * spacing. Asymmetric: at (2c + r % 2, r) * spacing.
    Edges are anti-aliased by a one-pixel linear ramp of the distance to the centre, which is
    symmetric about the centre and so does not move it.
    """
    width = (cols if symmetric else 2 * cols - 1) * _TEX_PX
    height = rows * _TEX_PX
    pad = _TEX_MARGIN
    v, u = np.indices((height + 2 * pad, width + 2 * pad), dtype=np.float64) - pad
    gy = v / _TEX_PX  # grid units; pixel centres at integers, circle centres on the grid nodes
    gx = u / _TEX_PX
    r = np.clip(np.round(gy), 0, rows - 1)
    if symmetric:
        c = np.clip(np.round(gx), 0, cols - 1)
    else:
        c = np.clip(2 * np.round((gx - r % 2) / 2), 0, 2 * cols - 2) + r % 2
    dist_px = np.hypot(gx - c, gy - r) * _TEX_PX
    dark = np.clip(0.3 * _TEX_PX - dist_px + 0.5, 0.0, 1.0)
    s = _TEX_PX / spacing
    tex_from_board = np.array([[s, 0.0, pad], [0.0, s, pad], [0.0, 0.0, 1.0]])
    return Texture(np.round(255.0 * (1.0 - dark)).astype(np.uint8), tex_from_board)


def charuco_texture(board: cv2.aruco.CharucoBoard) -> Texture:
    """Return OpenCV's rendering of a ChArUco board; model origin at the board's outer corner."""
    sx, sy = board.getChessboardSize()
    img = board.generateImage((sx * _TEX_PX, sy * _TEX_PX), marginSize=0)
    tex = np.pad(img, _TEX_MARGIN, constant_values=255)
    return Texture(tex, _board_to_texture(board.getSquareLength(), _TEX_MARGIN))


@cache
def _undistorted_grid(k: bytes, dist: bytes) -> tuple[Array, Array]:
    """Return normalised ideal coordinates (x, y), each (h*f, w*f), of every photo sub-pixel.

    Inverts OpenCV's distortion by its own fixed-point iteration (as cv2.undistortPoints does),
    vectorised: 20 iterations reach 1e-12 px for this lens, where 5 leave 1e-3 px.
    """
    K = np.frombuffer(k).reshape(3, 3)
    k1, k2, p1, p2, k3 = np.frombuffer(dist)
    f = _SUPERSAMPLE
    w, h = IMAGE_SIZE
    ys, xs = np.indices((h * f, w * f), dtype=np.float64)
    # Centre of sub-pixel (xs, ys) in photo pixel coordinates (pixel centres at integers).
    u = (xs + 0.5) / f - 0.5
    v = (ys + 0.5) / f - 0.5
    yd = (v - K[1, 2]) / K[1, 1]
    xd = (u - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    x, y = xd.copy(), yd.copy()
    for _ in range(20):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        x = (xd - (2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x))) / radial
        y = (yd - (p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)) / radial
    return x, y


def render_view(
    texture: Texture,
    model_points: Array,
    rvec: Array,
    tvec: Array,
    rng: np.random.Generator,
    *,
    K: Array = TRUE_K,
    dist: Array = TRUE_DIST,
    blur_sigma: float = 0.6,
    noise_sigma: float = 2.0,
) -> View:
    """Return a grey 640x480 photo of the board seen from (rvec, tvec) and its ground truth.

    model_points: (N, 3) board model points, metres, Z = 0. blur_sigma: Gaussian optical blur in
    px; noise_sigma: additive Gaussian sensor noise in grey levels (8 bit). The board is printed
    with black at 30 and white at 220 grey levels, on a mid-grey background, under a mild
    left-to-right illumination gradient.
    """
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    H = np.column_stack([R[:, 0], R[:, 1], np.asarray(tvec, dtype=np.float64)])  # normalised
    x, y = _undistorted_grid(K.tobytes(), np.resize(np.asarray(dist, np.float64), 5).tobytes())
    M = texture.tex_from_board @ np.linalg.inv(H)  # ideal normalised point -> texture px
    den = M[2, 0] * x + M[2, 1] * y + M[2, 2]
    mapx = ((M[0, 0] * x + M[0, 1] * y + M[0, 2]) / den).astype(np.float32)
    mapy = ((M[1, 0] * x + M[1, 1] * y + M[1, 2]) / den).astype(np.float32)
    mapx[den <= 0.0] = -1e6  # rays that meet the board plane behind the camera see the wall
    w, h = IMAGE_SIZE
    # Outside the texture: a mid-grey wall (128 grey levels once printed contrast is applied).
    wall = (128.0 - 30.0) * 255.0 / (220.0 - 30.0)
    hi = cv2.remap(
        texture.image.astype(np.float32),
        mapx,
        mapy,
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=wall,
    )
    img = cv2.resize(hi, (w, h), interpolation=cv2.INTER_AREA)  # exact 3x3 box filter
    img = 30.0 + (220.0 - 30.0) / 255.0 * img
    img *= np.linspace(0.85, 1.1, w, dtype=np.float32)[None, :]
    img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    img += rng.normal(0.0, noise_sigma, img.shape).astype(np.float32)
    photo = np.clip(np.round(img), 0, 255).astype(np.uint8)
    truth, _ = cv2.projectPoints(np.asarray(model_points, dtype=np.float64), rvec, tvec, K, dist)
    return View(photo, np.asarray(rvec, float), np.asarray(tvec, float), truth.reshape(-1, 2))


def board_poses(center: Array, distance: float, n: int = 6) -> list[tuple[Array, Array]]:
    """Return n (rvec, tvec) poses looking at the board point `center` (metres, board frame).

    Tilts of 20-35 degrees about varied axes (what makes Zhang's problem well conditioned), the
    board centre near the optical axis at `distance` metres, small in-plane rotations.
    """
    tilts = [
        (25.0, 0.0, 3.0),
        (-25.0, 5.0, -4.0),
        (0.0, 30.0, 2.0),
        (5.0, -30.0, -3.0),
        (20.0, 22.0, 6.0),
        (-20.0, -22.0, -6.0),
        (30.0, -10.0, 0.0),
        (-15.0, 28.0, 8.0),
    ][:n]
    offsets = [(0.01, -0.01), (-0.012, 0.008), (0.0, 0.012), (0.01, 0.0), (-0.01, -0.01)]
    poses = []
    for i, (ax, ay, az) in enumerate(tilts):
        R, _ = cv2.Rodrigues(np.deg2rad([ax, 0.0, 0.0]))
        Ry, _ = cv2.Rodrigues(np.deg2rad([0.0, ay, 0.0]))
        Rz, _ = cv2.Rodrigues(np.deg2rad([0.0, 0.0, az]))
        Rm = R @ Ry @ Rz
        dx, dy = offsets[i % len(offsets)]
        t = np.array([dx, dy, distance]) - Rm @ np.asarray(center, dtype=np.float64)
        rvec, _ = cv2.Rodrigues(Rm)
        poses.append((rvec.ravel(), t))
    return poses


def chessboard_model(cols: int, rows: int, square: float) -> Array:
    """Return (cols*rows, 3) inner-corner model points, row by row, metres.

    Written out here rather than taken from core's board_object_points, so that the truth does
    not depend on the code under test.
    """
    r, c = np.divmod(np.arange(cols * rows), cols)
    return np.column_stack([c * square, r * square, np.zeros(cols * rows)])


def render_chessboard_views(
    n: int = 6, cols: int = 9, rows: int = 6, square: float = 0.025, seed: int = 7
) -> list[View]:
    """Return n photos of a cols x rows (inner corners) chessboard with `square` metre squares."""
    rng = np.random.default_rng(seed)
    tex = chessboard_texture(cols, rows, square)
    model = chessboard_model(cols, rows, square)
    center = np.array([(cols - 1) * square / 2, (rows - 1) * square / 2, 0.0])
    return [render_view(tex, model, rv, tv, rng) for rv, tv in board_poses(center, 0.42, n)]


def write_views(views: list[View], folder: Path) -> list[Path]:
    """Write the photos as view_00.png ... into `folder`; return their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, v in enumerate(views):
        p = folder / f"view_{i:02d}.png"
        cv2.imwrite(str(p), v.image)
        paths.append(p)
    return paths


# Captured while this file is being imported: pytest may later bind the name "conftest" in
# sys.modules to another directory's conftest.
_THIS_MODULE = sys.modules[__name__]


@pytest.fixture(scope="session")
def photos() -> ModuleType:
    """This module: the renderer, the true camera and the board models."""
    return _THIS_MODULE


@pytest.fixture(scope="session")
def chessboard_views() -> list[View]:
    """Six rendered photos of a 9x6 chessboard with 25 mm squares."""
    return render_chessboard_views()
