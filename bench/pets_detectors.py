"""The people detectors on the PETS clip: their boxes scored against the ground truth's at IoU
0.5 (one-to-one, a conf 0 person neither a hit nor a miss) and their frames per second per core
(thread CPU time) at 768 x 576 and 640 x 480."""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from bench.pets_clip import SIZE, Array, Truth

IOU = 0.5  # a detector's box is a hit at this IoU with a ground-truth box (PASCAL)


@dataclass(frozen=True)
class BoxScore:
    """Hits, false positives and misses of a detector's boxes at IoU 0.5."""

    hits: int
    false_positives: int
    misses: int

    @property
    def precision(self) -> float:
        return self.hits / max(self.hits + self.false_positives, 1)

    @property
    def recall(self) -> float:
        return self.hits / max(self.hits + self.misses, 1)


def box_iou(a: Array, b: Array) -> Array:
    """Return the IoU of every box of `a` (N, 4) with every box of `b` (M, 4), x0, y0, x1, y1:
    (N, M)."""
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    inter = np.maximum(w, 0) * np.maximum(h, 0)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return inter / (area_a[:, None] + area_b[None, :] - inter)


def score_boxes(truth: Truth, boxes_by_frame: dict[int, Array]) -> BoxScore:
    """Return the hits, false positives and misses of the boxes (frame (1-based) -> (N, 4)
    x0, y0, x1, y1) against the truth's boxes of those frames, one-to-one (Hungarian on IoU),
    a hit at IoU >= 0.5; a box matched to a conf 0 person counts neither way."""
    hits = fps = misses = 0
    for frame, boxes in boxes_by_frame.items():
        rows = truth.rows(frame)
        gt, conf = truth.box[rows], truth.conf[rows]
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        matched_gt = np.zeros(0, dtype=np.int64)
        matched_b = np.zeros(0, dtype=np.int64)
        if len(gt) and len(b):
            iou = box_iou(gt, b)
            r, c = linear_sum_assignment(-iou)
            ok = iou[r, c] >= IOU
            matched_gt, matched_b = r[ok], c[ok]
        counted = conf[matched_gt] == 1
        hits += int(counted.sum())
        misses += int((conf == 1).sum() - counted.sum())
        fps += len(b) - len(matched_b)
    return BoxScore(hits, fps, misses)


@dataclass(frozen=True)
class DetectorResult:
    name: str
    score: BoxScore
    fps_by_size: dict[tuple[int, int], float]


def measure_detectors(frames: list[NDArray[np.uint8]], truth: Truth) -> list[DetectorResult]:
    """Return each detector's box score on the frames (frame k is ground-truth frame k + 1)
    and its frames per second per core (thread CPU time) at 768 x 576 and 640 x 480."""
    from core.localization.detect import PersonDetector
    from core.localization.ssd_people import (
        FLOAT_MODEL,
        SsdConfig,
        SsdPeopleDetector,
        default_model_path,
    )

    cv2.setNumThreads(1)
    results = []

    def timed(detect, images) -> float:
        start = time.thread_time()
        for image in images:
            detect(image)
        return len(images) / (time.thread_time() - start)

    # dnn: the node's default (the 8-bit model over 230 px tiles, each enlarged 1.3 times to the
    # model's input), the float model it was quantized from on the same tiles, the camera's own
    # resolution (300 px tiles, the model's input, as the node cut frames before), a costlier
    # candidate (each tile detected in its mirror image too, the two views merged), and the
    # whole frame in one pass (the model shrinks it to 300 x 300).
    native = SsdConfig(tile_px=300, tile_overlap_px=64, row_overlap_px=64)
    candidates = [
        ("dnn (8-bit, 230 px tiles)", None, SsdConfig()),
        ("dnn, float model, 230 px tiles", FLOAT_MODEL, SsdConfig()),
        ("dnn, 8-bit, 300 px tiles", None, native),
        ("dnn, 230 px tiles and mirror images", None, SsdConfig(flip=True)),
        ("dnn, whole frame", None, SsdConfig(tile_px=max(SIZE))),
    ]
    for name, model_name, config in candidates:
        model = None if model_name is None else default_model_path(model_name)
        dnn = SsdPeopleDetector(model, config=config)
        boxes = {k + 1: dnn.detect_boxes(image).boxes for k, image in enumerate(frames)}
        speed = {}
        for size in (SIZE, (640, 480)):
            images = [cv2.resize(f, size, interpolation=cv2.INTER_AREA) for f in frames[:40]]
            speed[size] = timed(SsdPeopleDetector(model, config=config).detect_boxes, images)
        results.append(DetectorResult(name, score_boxes(truth, boxes), speed))

    # background: the node's learning (its first 30 frames teach the model), then the blobs.
    learn = 30
    model = PersonDetector()
    boxes = {}
    for k, image in enumerate(frames):
        if k < learn:
            model.learn(image)
            continue
        found = model.detect(image)
        boxes[k + 1] = np.array(
            [[x, y, x + w, y + h] for x, y, w, h in (p.bbox for p in found)], dtype=np.float64
        ).reshape(-1, 4)
    speed = {}
    for size in (SIZE, (640, 480)):
        images = [cv2.resize(f, size, interpolation=cv2.INTER_AREA) for f in frames[:80]]
        m = PersonDetector()
        for image in images[:learn]:
            m.learn(image)
        speed[size] = timed(m.detect, images[learn:])
    results.append(DetectorResult("background (MOG2 blobs)", score_boxes(truth, boxes), speed))
    return results
