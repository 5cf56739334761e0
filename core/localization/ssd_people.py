"""People in real images as the boxes of a neural detector: SSDLite-MobileNetV2 trained on COCO,
run on the CPU by onnxruntime over the whole image at the camera's own resolution.

The model (core/localization/models/, converted once from TensorFlow's object detection model
zoo, see its README) is its feature extractor and box predictor: convolutions only, so it takes
an image of any size. The model zoo's graph resized every image to 300 x 300 pixels, where a
768 x 576 frame shrinks 2.6 times and a person 30 m away, 70 pixels tall, reaches the network
27 pixels tall, below the smallest boxes it was trained to find. Here the frame goes in whole,
at its own resolution (or shrunk only as far as the camera's geometry allows, `frame_scale`),
and the predictor's anchors are laid on each layer's grid at their pixel sizes of the 300 x 300
training images (`anchor_boxes`): every person is seen whole, at the scale the network knows,
in one pass (9 overlapping 300 px tiles before: 1.8 times the pixels and seams to mend).

The boxes are decoded as the model zoo's graph decoded them (Faster R-CNN box coder, scale
factors 10, 10, 5, 5), only the "person" class is kept, with a score of at least
`score_threshold` and a box at least `min_person_px` tall, and overlapping boxes are merged by
non-maximum suppression (`nms_iou`). A box that stops at the image's edge or a mask has that
side marked cut: a cut bottom gives no floor position (core.localization.boxes.box_foot).
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
from core.localization._projection import project_plane
from core.localization.boxes import BOX_SIDES, box_foot
from core.localization.cameras import NetworkCamera
from core.localization.detect import BodyModel
from core.localization.detections import FrameDetection
from core.localization.ground import PointStatus, locate_monocular

Array = NDArray[np.float64]

# The model shipped with the project (package data of core.localization.models).
DEFAULT_MODEL = "ssdlite_mobilenet_v2_coco.onnx"
# The side (px) of the square images the model was trained on, which its anchors are sized for.
MODEL_INPUT_PX = 300
# The model's anchors (the model zoo's ssdlite_mobilenet_v2_coco pipeline: six layers, scales
# from 0.2 to 0.95 of the input's side, aspect ratios 1, 2, 1/2, 3, 1/3 and one more square
# between a layer's scale and the next's; the lowest layer only a 0.1 square and 0.2 at 2 and
# 1/2). The grid of layer k is the model's own; the boxes laid on it are these.
ANCHOR_SCALES = (0.2, 0.35, 0.5, 0.65, 0.8, 0.95)
ANCHOR_RATIOS = (1.0, 2.0, 0.5, 3.0, 1.0 / 3.0)
# The Faster R-CNN box coder's scale factors (y, x, h, w) the model was trained with.
BOX_CODER_SCALE = (10.0, 10.0, 5.0, 5.0)
# The smallest anchor is 0.1 x 300 = 30 px square: a person shorter than that at the model's
# input matches no anchor and is not looked for.
SMALLEST_ANCHOR_PX = 30.0
# The smallest person-shaped anchor is 0.2 x 300 / sqrt(0.5) = 85 px tall and 42 px wide
# (aspect 0.5). A standing person's box (0.4 as wide as tall) inside it matches it at IoU 0.5,
# the matcher's threshold in training, from 0.4 h^2 / (85 x 42) = 0.5: h = 67 px. A frame is
# shrunk no further than to show its smallest person this tall.
PERSON_ANCHOR_PX = 67.0
# The person's class among the predictor's two (0 is the background).
PERSON_CLASS = 1
# A box side within this many pixels of an edge (the image's, a mask's) touches it: the
# model's boxes are regressed to about a pixel, and a box that stops at an edge is clipped
# there exactly.
EDGE_PX = 2.0
# The model's tensors (the names TensorFlow's export gave them, kept by the converter): the
# preprocessed image (RGB scaled to [-1, 1], NCHW), the box encodings (N, A, 1, 4), the class
# logits (N, A, 2) and each layer's class predictor, whose shape gives the layer's grid.
_INPUT = "Preprocessor/sub:0"
_BOXES = "concat:0"
_LOGITS = "concat_1:0"
_LAYERS = [f"BoxPredictor_{k}/ClassPredictor/BiasAdd:0" for k in range(len(ANCHOR_SCALES))]
# The least side (px) of an image the network takes (its deepest layers need a few pixels):
# smaller images are padded to it.
_LEAST_SIDE = MODEL_INPUT_PX


@dataclass(frozen=True)
class SsdConfig:
    """The neural person detector's settings.

    score_threshold: the least score of a kept box (0.5, the model zoo's own threshold for
    showing a detection); min_person_px: the least box height (px) of a person; nms_iou: the
    IoU above which two boxes are one person (0.5, PASCAL's match criterion); threads:
    onnxruntime's threads (1: a camera per core); person_px: with the camera's calibration, the
    height (px, at the model's input) of the smallest person on the camera's floor that the
    frame may be shrunk to (PERSON_ANCHOR_PX; `frame_scale`).
    """

    score_threshold: float = 0.5
    min_person_px: float = 20.0
    nms_iou: float = 0.5
    threads: int = 1
    person_px: float = PERSON_ANCHOR_PX

    def __post_init__(self) -> None:
        if not 0.0 <= self.score_threshold <= 1.0:
            raise InvalidInput(f"score_threshold must lie in [0, 1], got {self.score_threshold}")
        if not self.min_person_px >= 0:
            raise InvalidInput(f"min_person_px must be >= 0, got {self.min_person_px}")
        if not 0.0 < self.nms_iou <= 1.0 or self.threads < 1:
            raise InvalidInput("nms_iou must lie in (0, 1] and threads be >= 1")
        if not SMALLEST_ANCHOR_PX <= self.person_px <= MODEL_INPUT_PX:
            raise InvalidInput(
                f"person_px must lie in [{SMALLEST_ANCHOR_PX:g}, {MODEL_INPUT_PX}], got "
                f"{self.person_px}"
            )


@dataclass(frozen=True)
class PersonBoxes:
    """N people's boxes: boxes (N, 4) x0, y0, x1, y1 px; scores (N,) in [0, 1]; cut (N, 4)
    bool, the sides (BOX_SIDES order: bottom, top, left, right) that stop at the image's edge
    or a mask rather than at the person."""

    boxes: Array
    scores: Array
    cut: NDArray[np.bool_]

    def __len__(self) -> int:
        return int(self.boxes.shape[0])


def default_model_path() -> Path:
    """Return the path of the model installed with the project (package data)."""
    path = Path(str(resources.files("core.localization.models").joinpath(DEFAULT_MODEL)))
    if not path.is_file():
        raise InvalidInput(
            f"the person detector's model {DEFAULT_MODEL} is not installed beside "
            "core/localization/models: reinstall intspace"
        )
    return path


def anchor_boxes(grids: Sequence[tuple[int, int]], size: tuple[int, int]) -> Array:
    """Return the anchors (A, 4) ymin, xmin, ymax, xmax px of the model's layers for an input
    of `size` (width, height) px whose layers have the grids (rows, columns) `grids`, in the
    predictor's order (layer, row, column, anchor).

    As TensorFlow's SSD anchor generator lays them (ssd_anchor_generator, ANCHOR_SCALES and
    ANCHOR_RATIOS): anchor centres at the middles of the grid's cells over the input; each box
    of scale s and aspect ratio a (width over height) is s sqrt(a) by s / sqrt(a) times 300 px,
    the side of the training images, so that an anchor keeps the size in pixels the network
    learnt for it whatever the input's size. For a 300 x 300 input this is the model zoo's own
    anchor set."""
    width, height = size
    scales = (*ANCHOR_SCALES, 1.0)
    out = []
    for k, (rows, cols) in enumerate(grids):
        if k == 0:
            shapes = [(0.1, 1.0), (scales[0], 2.0), (scales[0], 0.5)]
        else:
            shapes = [(scales[k], a) for a in ANCHOR_RATIOS]
            shapes.append((float(np.sqrt(scales[k] * scales[k + 1])), 1.0))
        s = np.array([p[0] for p in shapes])
        a = np.array([p[1] for p in shapes])
        h = MODEL_INPUT_PX * s / np.sqrt(a)
        w = MODEL_INPUT_PX * s * np.sqrt(a)
        cy = (np.arange(rows) + 0.5) * height / rows
        cx = (np.arange(cols) + 0.5) * width / cols
        y = np.broadcast_to(cy[:, None, None], (rows, cols, len(shapes))).ravel()
        x = np.broadcast_to(cx[None, :, None], (rows, cols, len(shapes))).ravel()
        hh = np.broadcast_to(h, (rows, cols, len(shapes))).ravel()
        ww = np.broadcast_to(w, (rows, cols, len(shapes))).ravel()
        out.append(np.stack([y - hh / 2, x - ww / 2, y + hh / 2, x + ww / 2], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 4))


def decode_boxes(encodings: Array, anchors: Array) -> Array:
    """Return the boxes (A, 4) x0, y0, x1, y1 px of the box encodings (A, 4) ty, tx, th, tw
    relative to `anchors` (A, 4) ymin, xmin, ymax, xmax px: the Faster R-CNN box coder
    (Ren et al. 2015, eq. 2) with BOX_CODER_SCALE, as the model zoo's graph decodes them."""
    ha = anchors[:, 2] - anchors[:, 0]
    wa = anchors[:, 3] - anchors[:, 1]
    yc = 0.5 * (anchors[:, 0] + anchors[:, 2]) + encodings[:, 0] / BOX_CODER_SCALE[0] * ha
    xc = 0.5 * (anchors[:, 1] + anchors[:, 3]) + encodings[:, 1] / BOX_CODER_SCALE[1] * wa
    h = np.exp(encodings[:, 2] / BOX_CODER_SCALE[2]) * ha
    w = np.exp(encodings[:, 3] / BOX_CODER_SCALE[3]) * wa
    return np.stack([xc - w / 2, yc - h / 2, xc + w / 2, yc + h / 2], axis=1)


# Columns sampled per image row to bound a person's image height there.
_COLUMNS = 17


def person_heights(camera: NetworkCamera, body: BodyModel | None = None) -> tuple[Array, Array]:
    """Return, per image row v (H,), the least and the greatest image height (px) of a standing
    person whose feet are on that row: a short one (body.height - 2 height_sigma) anywhere
    along the row, a tall one (+ 2 height_sigma); NaN where the row's rays miss the floor in
    front of the camera (above the horizon)."""
    if camera.image_size is None:
        raise InvalidInput("the camera's image size is needed to know its people's sizes")
    mdl = body or BodyModel()
    width, height = camera.image_size
    u = np.linspace(0.0, width - 1.0, _COLUMNS)
    v = np.arange(height, dtype=np.float64)
    feet = np.stack(np.broadcast_arrays(u[None, :], v[:, None]), axis=-1).reshape(-1, 2)
    floor = locate_monocular(camera, feet, 0.0)
    ok = floor.status == PointStatus.OK
    out = []
    for stature in (mdl.height - 2.0 * mdl.height_sigma, mdl.height + 2.0 * mdl.height_sigma):
        h = np.full(feet.shape[0], np.nan)
        if ok.any():
            head = project_plane(camera, floor.point[ok, :2], stature)
            good = head.depth > 0
            h[np.flatnonzero(ok)[good]] = feet[ok, 1][good] - head.pixels[good, 1]
        out.append(h.reshape(height, _COLUMNS))
    with np.errstate(all="ignore"):
        short = np.where(np.isnan(out[0]).all(axis=1), np.nan, np.nanmin(out[0], axis=1))
        tall = np.where(np.isnan(out[1]).all(axis=1), np.nan, np.nanmax(out[1], axis=1))
    return short, tall


@dataclass(frozen=True)
class FrameView:
    """What of a camera's frame the detector looks at: rows [top, height) px of the frame,
    shrunk by `scale` (<= 1)."""

    top: int
    scale: float


def frame_scale(
    camera: NetworkCamera, config: SsdConfig | None = None, body: BodyModel | None = None
) -> FrameView:
    """Return the part of a placed camera's frames worth detecting in, and by how much it may
    be shrunk.

    A row of feet is worth looking at when a tall person standing there (person_heights) is at
    least the model's smallest anchor (SMALLEST_ANCHOR_PX) and `config.min_person_px` tall;
    the rows above the highest head of those people hold nobody the detector could find. The
    frame is shrunk by s = min(1, person_px / h) for the shortest person h on those rows, so
    that nobody becomes smaller than the smallest person-shaped anchor matches (never
    enlarged). A ceiling camera over a room, whose people are all hundreds of pixels tall,
    is looked at at a fraction of its pixels; a camera over a campus, whose far people are
    barely `person_px` tall, at its full resolution."""
    cfg = config or SsdConfig()
    short, tall = person_heights(camera, body)
    smallest = max(SMALLEST_ANCHOR_PX, cfg.min_person_px)
    rows = np.flatnonzero(np.isfinite(short) & np.isfinite(tall) & (tall >= smallest))
    if not rows.size:
        return FrameView(top=0, scale=1.0)
    head = rows - tall[rows] - EDGE_PX
    top = int(max(0.0, np.floor(np.min(head))))
    scale = float(min(1.0, cfg.person_px / np.min(short[rows])))
    return FrameView(top=top, scale=scale)


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
        options.log_severity_level = 3
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
        wanted = {_BOXES, _LOGITS, *_LAYERS}
        if _INPUT not in {i.name for i in self._session.get_inputs()} or not names >= wanted:
            raise InvalidInput(
                f"the model must take {_INPUT} and give {', '.join(sorted(wanted))}: "
                "SSDLite-MobileNetV2's feature extractor and box predictor "
                "(core/localization/models/README.md)"
            )
        self.mask = mask
        self._anchors: dict[tuple[int, int], Array] = {}
        self._view: tuple[NetworkCamera, FrameView] | None = None

    def view(self, camera: NetworkCamera | None, size: tuple[int, int]) -> FrameView:
        """Return what of a frame of `size` (width, height) this detector looks at: for a
        placed camera of that size `frame_scale` (kept: worked out once), else all of it at
        its own resolution."""
        if camera is None or camera.image_size != tuple(size):
            return FrameView(top=0, scale=1.0)
        if self._view is None or self._view[0] is not camera:
            self._view = (camera, frame_scale(camera, self.config))
        return self._view[1]

    def _network_boxes(self, rgb: NDArray[np.uint8]) -> tuple[Array, Array]:
        """Return the person boxes (M, 4) x0, y0, x1, y1 px in an RGB image and their scores
        (M,), scored at least score_threshold, before non-maximum suppression."""
        h, w = rgb.shape[:2]
        x = rgb.astype(np.float32) * np.float32(2.0 / 255.0) - np.float32(1.0)
        ph, pw = max(h, _LEAST_SIDE), max(w, _LEAST_SIDE)
        if (ph, pw) != (h, w):
            # Mid-grey (0 after scaling) beyond the image: nothing there for the model.
            x = np.pad(x, ((0, ph - h), (0, pw - w), (0, 0)))
        tensor = np.ascontiguousarray(x.transpose(2, 0, 1)[None])
        encodings, logits, *layers = self._session.run(
            [_BOXES, _LOGITS, *_LAYERS], {_INPUT: tensor}
        )
        grids = tuple((int(a.shape[2]), int(a.shape[3])) for a in layers)
        anchors = self._anchors.get((pw, ph))
        if anchors is None or anchors.shape[0] != encodings.shape[1]:
            anchors = anchor_boxes(grids, (pw, ph))
            if anchors.shape[0] != encodings.shape[1]:
                raise InvalidInput(
                    f"the model gave {encodings.shape[1]} boxes for {len(anchors)} anchors: "
                    "not SSDLite-MobileNetV2's box predictor"
                )
            self._anchors[(pw, ph)] = anchors
        score = 1.0 / (1.0 + np.exp(-logits[0, :, PERSON_CLASS].astype(np.float64)))
        keep = np.flatnonzero(score >= self.config.score_threshold)
        boxes = decode_boxes(encodings[0, keep, 0].astype(np.float64), anchors[keep])
        # Clipped to the image, as the model zoo's graph clips them to its window.
        boxes = np.clip(boxes, 0.0, [w, h, w, h])
        return boxes, score[keep]

    def detect_boxes(
        self, image: NDArray[np.uint8], camera: NetworkCamera | None = None
    ) -> PersonBoxes:
        """Return the people in a BGR image (H, W, 3) as boxes, scores and cut sides; with the
        camera's calibration (`camera`), in the part of the frame and at the scale its
        geometry allows (`frame_scale`)."""
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise InvalidInput(f"image must be BGR uint8 (H, W, 3), got {img.dtype} {img.shape}")
        height, width = img.shape[:2]
        cfg = self.config
        view = self.view(camera, (width, height))
        part: NDArray[np.uint8] = img[view.top :, :, ::-1]
        if view.scale < 1.0:
            size = (
                max(1, round(part.shape[1] * view.scale)),
                max(1, round(part.shape[0] * view.scale)),
            )
            part = np.asarray(
                cv2.resize(np.ascontiguousarray(part), size, interpolation=cv2.INTER_AREA), np.uint8
            )
            sx, sy = width / size[0], (height - view.top) / size[1]
        else:
            sx = sy = 1.0
        boxes, score = self._network_boxes(part)
        boxes = boxes * [sx, sy, sx, sy] + [0.0, view.top, 0.0, view.top]
        tall = (boxes[:, 3] - boxes[:, 1] >= max(cfg.min_person_px, 1e-9)) & (
            boxes[:, 2] > boxes[:, 0]
        )
        boxes, score = boxes[tall], score[tall]
        keep = _nms(boxes, score, cfg.nms_iou)
        boxes, score = boxes[keep], score[keep]
        cut = box_cuts(boxes, (width, height), self.mask)
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
        robot's pixels change nothing: the boxes are people, not blobs that could be the
        robot's body."""
        found = self.detect_boxes(image, camera)
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


def _nms(boxes: Array, scores: Array, iou: float) -> NDArray[np.int64]:
    """Return the indices of the boxes kept by greedy non-maximum suppression, best first."""
    if not boxes.shape[0]:
        return np.zeros(0, dtype=np.int64)
    xywh = np.column_stack([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]])
    kept = cv2.dnn.NMSBoxes(xywh.tolist(), scores.tolist(), 0.0, iou)
    return np.asarray(kept, dtype=np.int64).reshape(-1)
