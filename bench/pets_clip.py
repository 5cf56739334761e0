"""The PETS 2009 S2.L1 View_001 clip and its ground truth: where they are, the MOTChallenge
rows (boxes, ids, floor positions), the clip's frames and a lossless copy of its first frames.

The video is Debian's opencv-doc `examples/data/vtest.avi` (INTSPACE_PETS_VIDEO, default
/var/cache/intspace/vtest.avi; .ci/run installs it); the ground truth is
../shared/data/pets2009-s2l1/gt-frames-001-400.txt (INTSPACE_PETS_GT overrides).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

REPO = Path(__file__).resolve().parents[1]
VIDEO_ENV = "INTSPACE_PETS_VIDEO"
DEFAULT_VIDEO = "/var/cache/intspace/vtest.avi"
GT_ENV = "INTSPACE_PETS_GT"
DEFAULT_GT = REPO.parent / "shared" / "data" / "pets2009-s2l1" / "gt-frames-001-400.txt"
SIZE = (768, 576)
SOURCE_FPS = 7.0  # the footage's capture rate (its container says 10)

Array = NDArray[np.float64]


def video_path() -> Path:
    """Return where the clip is expected (INTSPACE_PETS_VIDEO or the default)."""
    return Path(os.environ.get(VIDEO_ENV, DEFAULT_VIDEO))


def truth_path() -> Path:
    """Return where the ground truth is expected (INTSPACE_PETS_GT or ../shared/data)."""
    return Path(os.environ.get(GT_ENV, str(DEFAULT_GT)))


@dataclass(frozen=True)
class Truth:
    """The ground truth's rows: frame (1-based), id, box (x0, y0, x1, y1) px, conf, world
    (x, y) m."""

    frame: NDArray[np.int64]
    ident: NDArray[np.int64]
    box: Array
    conf: NDArray[np.int64]
    world: Array

    def rows(self, frame: int) -> NDArray[np.bool_]:
        return self.frame == frame


def load_truth(path: Path | None = None) -> Truth:
    """Return the MOTChallenge rows of `path` (frame, id, left, top, width, height, conf,
    world_x, world_y, world_z)."""
    a = np.loadtxt(path or truth_path(), delimiter=",", ndmin=2)
    box = np.column_stack([a[:, 2], a[:, 3], a[:, 2] + a[:, 4], a[:, 3] + a[:, 5]])
    return Truth(
        frame=a[:, 0].astype(np.int64),
        ident=a[:, 1].astype(np.int64),
        box=box,
        conf=a[:, 6].astype(np.int64),
        world=a[:, 7:9].copy(),
    )


def read_frames(path: Path, count: int) -> list[NDArray[np.uint8]]:
    """Return the first `count` frames of the video (BGR)."""
    cap = cv2.VideoCapture(str(path))
    frames = []
    try:
        while len(frames) < count:
            ok, image = cap.read()
            if not ok:
                break
            frames.append(image)
    finally:
        cap.release()
    if not frames:
        raise SystemExit(f"cannot read {path}")
    return frames


def clip_video(source: Path, frames: int, out: Path) -> Path:
    """Write the first `frames` frames of `source` losslessly (FFV1) to `out`."""
    images = read_frames(source, frames)
    h, w = images[0].shape[:2]
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"FFV1"), 10.0, (w, h))
    if not writer.isOpened():
        raise RuntimeError("OpenCV cannot write FFV1 video here")
    for image in images:
        writer.write(image)
    writer.release()
    check = read_frames(out, 1)[0]
    if not np.array_equal(check, images[0]):
        raise RuntimeError("the FFV1 copy of the clip is not lossless")
    return out
