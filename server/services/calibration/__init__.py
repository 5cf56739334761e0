"""Calibration runs, one module per kind, each creating, computing and applying its runs:

* `intrinsics`: Zhang's calibration of one camera, from correspondences or chessboard photos;
* `network`: the twin's calibration drive, every twin camera's intrinsics and pose;
* `hand_eye`: an arm's eye-in-hand camera, on the twin or from uploaded pose pairs;
* `projector`: the twin's projector's mount, from spots the ceiling cameras locate;
* `placement`: a real camera placed from clicked floor points.

`kinds.KINDS` is the table the routes, the executor (server.services.runs) and apply use;
`io` reads images and writes calibration files.
"""

from server.services.calibration._shared import Progress, RunContext, RunRefused
from server.services.calibration.io import board_object_points_for, calibration_yaml, decode_image
from server.services.calibration.kinds import KINDS, RunKind, UnknownRunKind, kind_of
from server.services.calibration.network import network_calibration_drive

__all__ = [
    "KINDS",
    "Progress",
    "RunContext",
    "RunKind",
    "RunRefused",
    "UnknownRunKind",
    "board_object_points_for",
    "calibration_yaml",
    "decode_image",
    "kind_of",
    "network_calibration_drive",
]
