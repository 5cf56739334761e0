"""People in real images as the boxes of a neural detector: SSDLite-MobileNetV2 trained on COCO,
run on the CPU by onnxruntime, over tiles that magnify the frame.

The model (core/localization/models/, converted once from TensorFlow's object detection model
zoo and quantized once to 8-bit integers, see its README) resizes whatever it is given to
300 x 300 pixels. A whole 768 x 576 frame would shrink 2.6 times, and a person 30 m away, 65
pixels tall, would reach the network 25 pixels tall, below the smallest boxes it was trained to
find. So the frame is cut into square tiles of `tile_px` pixels that the model enlarges to its
input: 230 px tiles magnify 1.3 times, so that the same person reaches 85 px, the height of the
model's smallest upright anchor box (its lowest feature map's scale, 0.2 of the input, at
aspect ratio 1:2: 0.2 x 300 x sqrt(2)). The tiles overlap by at least `tile_overlap_px`
between columns and `row_overlap_px` between rows: a standing person is about 2.5 times as tall
as wide, and one shorter than the rows' overlap is whole in one of the two tiles above each
other (a person cut by a tile's bottom edge has no feet in it). At 768 x 576 that is 16 tiles
(4 x 4), at 640 x 480 12 (the bench measures the cost: bench/bench_pets.py).

A person on the seam between two tiles is seen whole by one of them when they are smaller
than the overlap; the other tile gives a part of them, cut by its edge. Boxes from all tiles
are merged by non-maximum suppression (`nms_iou`), a box cut by an inner tile edge is dropped
when another box holds most of it (`CONTAINED`), and two parts of one person that no tile saw
whole (one stops at a seam, the other starts there, over the same columns or rows) are joined
into one box (`_join_parts`). A box that remains cut by a tile's edge keeps that side marked
cut, like a box cut by the image's edge or a mask: a cut bottom gives no floor position
(core.localization.boxes.box_foot).

Only the COCO "person" class is kept, with a score of at least `score_threshold` and a box at
least `min_person_px` tall.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.localization.boxes import BOX_SIDES, box_foot
from core.localization.cameras import NetworkCamera
from core.localization.detections import FrameDetection

Array = NDArray[np.float64]

# The models shipped with the project (package data of core.localization.models): the network
# quantized to 8-bit integers (the default: about 1.7 times faster on a CPU with 8-bit dot
# products, as precise and as complete on PETS 2009, bench/bench_pets.py) and the float model
# it was quantized from.
DEFAULT_MODEL = "ssdlite_mobilenet_v2_coco_int8.onnx"
FLOAT_MODEL = "ssdlite_mobilenet_v2_coco.onnx"
# The model's input side (px): its graph resizes every image to this square.
MODEL_INPUT_PX = 300
# The tiles' side (px): the model enlarges each to its input, 300 / 230 = 1.3 times (module
# docstring), and 4 x 4 of them cover 768 x 576 with the overlaps below.
TILE_PX = 230
# The least overlap of neighbouring tiles (px): across columns, wider than a person up to 120 px
# tall (a standing person's box is at most about 0.4 times as wide as tall); across rows, taller
# than a person up to 100 px tall.
TILE_OVERLAP_PX = 48
ROW_OVERLAP_PX = 100
# The least score of a kept box: the model zoo's own threshold for showing a detection.
SCORE_THRESHOLD = 0.5
# The COCO label of a person in the TensorFlow model zoo's numbering (1-based, 1 = person).
COCO_PERSON = 1
# A box cut by a tile's inner edge is a part of someone another tile sees whole when at least
# this fraction of its area lies in another kept box.
CONTAINED = 0.6
# A box side within this many pixels of an edge (the image's, a tile's, a mask's) touches it:
# the model's boxes are regressed to about a pixel, and a box that stops at an edge is clipped
# there exactly.
EDGE_PX = 2.0
# The model's graph names (TensorFlow's object detection API export, kept by the converter).
_INPUT = "image_tensor:0"
_OUTPUTS = ["num_detections:0", "detection_scores:0", "detection_boxes:0", "detection_classes:0"]


@dataclass(frozen=True)
class SsdConfig:
    """The neural person detector's settings.

    score_threshold: the least score of a kept box (SCORE_THRESHOLD, with or
    without `flip`); min_person_px: the least box height (px) of a person; tile_px: the
    tiles' side in the image (px; the model resizes each to MODEL_INPUT_PX, so a smaller tile
    magnifies more and costs more tiles); tile_overlap_px: the least overlap between
    neighbouring tiles of a row (px; a person narrower than this is whole in one of them);
    row_overlap_px: the least overlap between rows of tiles (px; a person shorter than this is
    whole in one of them); nms_iou: the IoU above which two boxes are one
    person (0.5, PASCAL's match criterion); flip: also detect in each tile mirrored left to
    right and merge both by the same suppression (test-time augmentation: a person is a
    person in a mirror, the network's misses are not, at twice the cost); threads:
    onnxruntime's threads (1: a camera per core).
    """

    score_threshold: float = SCORE_THRESHOLD
    min_person_px: float = 20.0
    tile_px: int = TILE_PX
    tile_overlap_px: int = TILE_OVERLAP_PX
    row_overlap_px: int = ROW_OVERLAP_PX
    nms_iou: float = 0.5
    flip: bool = False
    threads: int = 1

    def __post_init__(self) -> None:
        if not 0.0 <= self.score_threshold <= 1.0:
            raise InvalidInput(f"score_threshold must lie in [0, 1], got {self.score_threshold}")
        if not self.min_person_px >= 0:
            raise InvalidInput(f"min_person_px must be >= 0, got {self.min_person_px}")
        overlaps = (self.tile_overlap_px, self.row_overlap_px)
        if self.tile_px < 32 or not all(0 <= o < self.tile_px // 2 for o in overlaps):
            raise InvalidInput(
                "tile_px must be >= 32 and tile_overlap_px and row_overlap_px in "
                f"[0, tile_px / 2), got {self.tile_px}, {self.tile_overlap_px} and "
                f"{self.row_overlap_px}"
            )
        if not 0.0 < self.nms_iou <= 1.0 or self.threads < 1:
            raise InvalidInput("nms_iou must lie in (0, 1] and threads be >= 1")


@dataclass(frozen=True)
class PersonBoxes:
    """N people's boxes: boxes (N, 4) x0, y0, x1, y1 px; scores (N,) in [0, 1]; cut (N, 4)
    bool, the sides (BOX_SIDES order: bottom, top, left, right) that stop at the image's edge,
    a mask or a tile's edge rather than at the person."""

    boxes: Array
    scores: Array
    cut: NDArray[np.bool_]

    def __len__(self) -> int:
        return int(self.boxes.shape[0])


def default_model_path(name: str = DEFAULT_MODEL) -> Path:
    """Return the path of a model installed with the project (package data): the default
    one, or FLOAT_MODEL."""
    path = Path(str(resources.files("core.localization.models").joinpath(name)))
    if not path.is_file():
        raise InvalidInput(
            f"the person detector's model {name} is not installed beside "
            "core/localization/models: reinstall intspace"
        )
    return path


def tile_origins(length: int, tile: int, overlap: int) -> list[int]:
    """Return the first pixel of each tile covering `length` pixels with tiles of `tile`
    pixels that overlap by at least `overlap`, spread evenly (one tile when it fits)."""
    if length <= tile:
        return [0]
    n = int(np.ceil((length - tile) / (tile - overlap))) + 1
    return [round(i * (length - tile) / (n - 1)) for i in range(n)]


def box_cuts(
    boxes: Array,
    size: tuple[int, int],
    mask: NDArray[np.bool_] | None = None,
    *,
    edge_px: float = EDGE_PX,
) -> NDArray[np.bool_]:
    """Return (N, 4) bool, the sides (BOX_SIDES order) of `boxes` (N, 4: x0, y0, x1, y1 px)
    that stop at the edge of an image of `size` (width, height) or at `mask` ((H, W) bool, the
    pixels hidden from the detector): a side is cut by the mask when at least half of the
    `edge_px`-wide band just outside it is masked."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    width, height = size
    cut = np.zeros((b.shape[0], len(BOX_SIDES)), dtype=bool)
    cut[:, BOX_SIDES.index("bottom")] = b[:, 3] >= height - 1 - edge_px
    cut[:, BOX_SIDES.index("top")] = b[:, 1] <= edge_px
    cut[:, BOX_SIDES.index("left")] = b[:, 0] <= edge_px
    cut[:, BOX_SIDES.index("right")] = b[:, 2] >= width - 1 - edge_px
    if mask is None or not b.shape[0]:
        return cut
    if mask.shape != (height, width):
        raise InvalidInput(f"the mask is {mask.shape[::-1]} px, the image {size}")
    integral = cv2.integral(mask.astype(np.uint8)).astype(np.float64)

    def masked_fraction(x0: Array, y0: Array, x1: Array, y1: Array) -> Array:
        # Pixel bands [x0, x1) x [y0, y1), clipped to the image: the fraction masked.
        xa = np.clip(np.floor(x0), 0, width).astype(int)
        xb = np.clip(np.ceil(x1), 0, width).astype(int)
        ya = np.clip(np.floor(y0), 0, height).astype(int)
        yb = np.clip(np.ceil(y1), 0, height).astype(int)
        area = (xb - xa) * (yb - ya)
        total = integral[yb, xb] - integral[ya, xb] - integral[yb, xa] + integral[ya, xa]
        return np.where(area > 0, total / np.maximum(area, 1), 0.0)

    x0, y0, x1, y1 = b.T
    e = edge_px + 1.0
    bands = {
        "bottom": (x0, y1, x1, y1 + e),
        "top": (x0, y0 - e, x1, y0),
        "left": (x0 - e, y0, x0, y1),
        "right": (x1, y0, x1 + e, y1),
    }
    for side, band in bands.items():
        cut[:, BOX_SIDES.index(side)] |= masked_fraction(*band) >= 0.5
    return cut


class SsdPeopleDetector:
    """People in BGR frames as the boxes of SSDLite-MobileNetV2 (COCO), one per camera.

    model: the ONNX model as bytes or a path (None: the model installed with the project);
    config: SsdConfig; mask: (H, W) bool, the pixels the camera's node hides from detection
    (a box that stops at them is cut there).
    """

    def __init__(
        self,
        model: bytes | str | os.PathLike[str] | None = None,
        *,
        config: SsdConfig | None = None,
        mask: NDArray[np.bool_] | None = None,
    ) -> None:
        import onnxruntime as ort  # loaded only by the cameras that use this detector

        self.config = config or SsdConfig()
        options = ort.SessionOptions()
        options.intra_op_num_threads = self.config.threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3  # the converted graph's unused outputs are not news
        source = str(default_model_path()) if model is None else model
        if isinstance(source, os.PathLike):
            source = os.fspath(source)
        try:
            self._session = ort.InferenceSession(
                source, options, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own untyped errors
            raise InvalidInput(f"not a usable ONNX person detector model: {exc}") from exc
        names = {o.name for o in self._session.get_outputs()}
        if _INPUT not in {i.name for i in self._session.get_inputs()} or not names >= set(_OUTPUTS):
            raise InvalidInput(
                f"the model must take {_INPUT} and give {', '.join(_OUTPUTS)} (a TensorFlow "
                "object detection API export)"
            )
        self.mask = mask

    def _detect_tile(self, rgb: NDArray[np.uint8]) -> tuple[Array, Array]:
        """Return the person boxes (M, 4) px in the tile and their scores (M,)."""
        count, scores, boxes, classes = self._session.run(
            _OUTPUTS, {_INPUT: np.ascontiguousarray(rgb[None])}
        )
        n = int(count[0])
        keep = (classes[0, :n] == COCO_PERSON) & (scores[0, :n] >= self.config.score_threshold)
        h, w = rgb.shape[:2]
        # The model gives (ymin, xmin, ymax, xmax) as fractions of the tile.
        b = boxes[0, :n][keep][:, [1, 0, 3, 2]].astype(np.float64) * [w, h, w, h]
        return b, scores[0, :n][keep].astype(np.float64)

    def _tile_boxes(
        self, rgb: NDArray[np.uint8], x0: int, y0: int, x1: int, y1: int
    ) -> tuple[Array, Array]:
        """Return the person boxes (M, 4) px, in the image's pixels, that the model finds in
        the tile [x0, x1) x [y0, y1) of the RGB image, and their scores (M,); with `flip`, also
        those it finds in the tile mirrored left to right, mirrored back."""
        tile = rgb[y0:y1, x0:x1]
        b, s = self._detect_tile(tile)
        if self.config.flip:
            fb, fs = self._detect_tile(tile[:, ::-1])
            w = x1 - x0
            fb = np.column_stack([w - fb[:, 2], fb[:, 1], w - fb[:, 0], fb[:, 3]])
            # Both views go to the suppression below: it keeps the better of a person's two
            # boxes, and the person that one view missed.
            b, s = np.concatenate([b, fb]), np.concatenate([s, fs])
        return b + np.array([x0, y0, x0, y0], dtype=np.float64), s

    def detect_boxes(self, image: NDArray[np.uint8]) -> PersonBoxes:
        """Return the people in a BGR image (H, W, 3) as boxes, scores and cut sides."""
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise InvalidInput(f"image must be BGR uint8 (H, W, 3), got {img.dtype} {img.shape}")
        height, width = img.shape[:2]
        rgb = img[:, :, ::-1]
        cfg = self.config
        found, scores, seams = [], [], []
        for y0 in tile_origins(height, cfg.tile_px, cfg.row_overlap_px):
            for x0 in tile_origins(width, cfg.tile_px, cfg.tile_overlap_px):
                x1, y1 = min(width, x0 + cfg.tile_px), min(height, y0 + cfg.tile_px)
                b, s = self._tile_boxes(rgb, x0, y0, x1, y1)
                # The sides that stop at this tile's inner edges (not the image's).
                seam = np.zeros((b.shape[0], len(BOX_SIDES)), dtype=bool)
                seam[:, 0] = (y1 < height) & (b[:, 3] >= y1 - 1 - EDGE_PX)
                seam[:, 1] = (y0 > 0) & (b[:, 1] <= y0 + EDGE_PX)
                seam[:, 2] = (x0 > 0) & (b[:, 0] <= x0 + EDGE_PX)
                seam[:, 3] = (x1 < width) & (b[:, 2] >= x1 - 1 - EDGE_PX)
                found.append(b)
                scores.append(s)
                seams.append(seam)
        boxes = np.concatenate(found)
        score = np.concatenate(scores)
        seam = np.concatenate(seams)
        tall = boxes[:, 3] - boxes[:, 1] >= cfg.min_person_px
        boxes, score, seam = boxes[tall], score[tall], seam[tall]
        keep = _nms(boxes, score, cfg.nms_iou)
        boxes, score, seam = boxes[keep], score[keep], seam[keep]
        part = seam.any(axis=1)
        if part.any():
            inside = _intersection(boxes, boxes) / _area(boxes)[:, None]
            np.fill_diagonal(inside, 0.0)
            # A part of someone is dropped when a box not cut by a seam holds most of it.
            held = (inside[:, ~part] >= CONTAINED).any(axis=1)
            boxes, score, seam = boxes[~(part & held)], score[~(part & held)], seam[~(part & held)]
            boxes, score, seam = _join_parts(boxes, score, seam)
        cut = box_cuts(boxes, (width, height), self.mask) | seam
        return PersonBoxes(boxes=boxes, scores=score, cut=cut)

    def detect_people(
        self,
        image: NDArray[np.uint8],
        *,
        camera: NetworkCamera | None = None,
        robot_pixels: Sequence[Array] = (),
    ) -> list[FrameDetection]:
        """Return a "person" detection (the foot point, height 0) for each box whose bottom is
        not cut (core.localization.boxes.box_foot); a cut bottom gives no floor position. The
        camera and the robot's pixels change nothing: the boxes are people, not blobs that
        could be the robot's body."""
        found = self.detect_boxes(image)
        if not len(found):
            return []
        foot = box_foot(found.boxes, found.cut)
        out = []
        for i in np.flatnonzero(foot.measured):
            x0, y0, x1, y1 = np.rint(found.boxes[i]).astype(int).tolist()
            bbox = (x0, y0, x1 - x0, y1 - y0)
            out.append(
                FrameDetection(
                    "person", foot.pixel[i], foot.cov[i], 0.0, bbox, float(found.scores[i])
                )
            )
        return out


def _join_parts(
    boxes: Array, scores: Array, seam: NDArray[np.bool_]
) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Return the boxes with the two parts of a person cut by a seam joined into one.

    A box whose bottom (right side) stops at a tile's inner edge and a box whose top (left
    side) starts at the next tile's inner edge, overlapping across the seam and, along it, by
    at least half of their extents (one-dimensional IoU >= 0.5), are one person seen by two
    tiles: their union, with the better score, cut where either is cut elsewhere."""
    b, s, c = boxes.copy(), scores.copy(), seam.copy()
    alive = np.ones(len(b), dtype=bool)
    bottom, top, left, right = (BOX_SIDES.index(n) for n in ("bottom", "top", "left", "right"))
    for first_side, second_side, axis in ((bottom, top, 1), (right, left, 0)):
        along = 1 - axis  # the coordinate along the seam
        for i in np.flatnonzero(alive & c[:, first_side]):
            j_all = np.flatnonzero(alive & c[:, second_side])
            j_all = j_all[
                (b[j_all, axis] > b[i, axis]) & (b[j_all, axis] < b[i, axis + 2])
            ]  # starts inside the first part: the tiles overlap there
            if not j_all.size:
                continue
            lo = np.maximum(b[i, along], b[j_all, along])
            hi = np.minimum(b[i, along + 2], b[j_all, along + 2])
            span = np.maximum(b[i, along + 2], b[j_all, along + 2]) - np.minimum(
                b[i, along], b[j_all, along]
            )
            iou = np.maximum(hi - lo, 0.0) / np.maximum(span, 1e-9)
            k = int(np.argmax(iou))
            if iou[k] < 0.5:
                continue
            j = int(j_all[k])
            b[i] = [min(b[i, 0], b[j, 0]), min(b[i, 1], b[j, 1]), max(b[i, 2], b[j, 2]),
                    max(b[i, 3], b[j, 3])]  # fmt: skip
            s[i] = max(s[i], s[j])
            joined = c[i] | c[j]
            joined[first_side] = c[j, first_side]
            joined[second_side] = c[i, second_side]
            c[i] = joined
            alive[j] = False
    return b[alive], s[alive], c[alive]


def _area(b: Array) -> Array:
    return np.maximum(b[:, 2] - b[:, 0], 0.0) * np.maximum(b[:, 3] - b[:, 1], 0.0)


def _intersection(a: Array, b: Array) -> Array:
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    return np.maximum(w, 0.0) * np.maximum(h, 0.0)


def _nms(boxes: Array, scores: Array, iou: float) -> NDArray[np.int64]:
    """Return the indices of the boxes kept by greedy non-maximum suppression, best first."""
    if not boxes.shape[0]:
        return np.zeros(0, dtype=np.int64)
    xywh = np.column_stack([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]])
    kept = cv2.dnn.NMSBoxes(xywh.tolist(), scores.tolist(), 0.0, iou)
    return np.asarray(kept, dtype=np.int64).reshape(-1)
