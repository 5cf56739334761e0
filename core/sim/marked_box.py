"""The box the fetch grasps and the mark printed on its top: its size, the chessboard and the
mark's points in the mark's frame (what the controller servoes on and the 3D scene draws)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from core.calibration import Chessboard, board_object_points
from core.sim.scene import Board

Array = NDArray[np.float64]

# The object: a box 0.16 m long, 0.115 m wide (the gripper closes across its width) and 0.10 m
# high, with its mark printed on the top: a chessboard of 7 x 6 squares of 16 mm (6 x 5 inner
# corners: 6 + 5 odd, so the detector tells the first corner from the last and the mark's yaw
# is not ambiguous) with an 8 mm white border, 128 x 112 mm in all.
MARK_BOARD = Board(inner_corners=(6, 5), square_size=0.016, margin=0.5)
BOX_SIZE = (0.16, 0.115, 0.10)
BOX_HEIGHT = BOX_SIZE[2]
# The board's frame (origin at the first inner corner, z into the box) in the mark's frame
# (origin at the centre of the top, z up out of the box, x along the board's columns).
_cx = (MARK_BOARD.inner_corners[0] - 1) * MARK_BOARD.square_size / 2
_cy = (MARK_BOARD.inner_corners[1] - 1) * MARK_BOARD.square_size / 2
T_MARK_BOARD = np.array(
    [[1.0, 0.0, 0.0, -_cx], [0.0, -1.0, 0.0, _cy], [0.0, 0.0, -1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
# The mark's points (its inner corners, in the detector's order) in the mark frame.
MARK_POINTS = (
    board_object_points(Chessboard(*MARK_BOARD.inner_corners), MARK_BOARD.square_size)
    @ T_MARK_BOARD[:3, :3].T
    + T_MARK_BOARD[:3, 3]
)
