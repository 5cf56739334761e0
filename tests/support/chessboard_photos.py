"""Synthetic chessboard photos for the calibration runs' tests: a 9 x 6 inner-corner board
(10 x 7 squares of 30 mm) seen by K_TRUE from a few poses (POSES), rendered with
cv2.warpPerspective from a flat board image, with pixel noise."""

from __future__ import annotations

import cv2
import numpy as np

K_TRUE = np.array([[700.0, 0.0, 320.0], [0.0, 700.0, 240.0], [0.0, 0.0, 1.0]])
SQUARE_M = 0.03
PX_PER_SQUARE = 60


def _board_image() -> np.ndarray:
    cols, rows, margin = 10, 7, PX_PER_SQUARE
    board = np.full((rows * PX_PER_SQUARE + 2 * margin, cols * PX_PER_SQUARE + 2 * margin), 255)
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2 == 0:
                y, x = margin + r * PX_PER_SQUARE, margin + c * PX_PER_SQUARE
                board[y : y + PX_PER_SQUARE, x : x + PX_PER_SQUARE] = 0
    return board.astype(np.uint8)


def chessboard_photo(rvec: list[float], tvec: list[float], seed: int) -> bytes:
    """Return a PNG of the board at pose (rvec, tvec) (board to camera, metres) through K_TRUE,
    640 x 480, with Gaussian noise of 2 grey levels drawn with `seed`."""
    board = _board_image()
    R, _ = cv2.Rodrigues(np.array(rvec, dtype=float))
    # Board pixel (u, v) -> board metres, with the first inner corner at the origin.
    metres_per_px = SQUARE_M / PX_PER_SQUARE
    offset = 2 * PX_PER_SQUARE  # margin + one square to the first inner corner
    B = np.array(
        [
            [metres_per_px, 0, -offset * metres_per_px],
            [0, metres_per_px, -offset * metres_per_px],
            [0, 0, 1],
        ]
    )
    H = K_TRUE @ np.column_stack([R[:, 0], R[:, 1], tvec]) @ B
    image = cv2.warpPerspective(board, H, (640, 480), flags=cv2.INTER_AREA, borderValue=255)
    noisy = image + np.random.default_rng(seed).normal(0, 2.0, image.shape)
    ok, png = cv2.imencode(".png", np.clip(noisy, 0, 255).astype(np.uint8))
    assert ok
    return png.tobytes()


POSES = [
    ([0.25, -0.2, 0.05], [-0.12, -0.08, 0.55]),
    ([-0.3, 0.15, -0.1], [-0.1, -0.07, 0.6]),
    ([0.1, 0.35, 0.2], [-0.14, -0.06, 0.6]),
    ([-0.2, -0.3, 0.0], [-0.11, -0.09, 0.65]),
]
