"""The background detector on real footage: PETS 2009 S2.L1 View_001 (Debian's opencv-doc
`examples/data/vtest.avi`), before and after it learnt to keep learning.

Run from the repository root, under nice (it decodes and detects 795 frames twice):

    apt-get download opencv-doc && dpkg-deb -x opencv-doc_*.deb /tmp/opencv-doc
    nice -n 10 python -m bench.pets_background \
        /tmp/opencv-doc/usr/share/doc/opencv-doc/examples/data/vtest.avi \
        /work/shared/data/pets2009-s2l1/gt-frames-001-400.txt

What a node does with the clip (server.node.runner): the first 30 frames teach the background
(`learn`), every later frame goes through core.localization.detections.detect_frame with the
product's robot marker and the camera's calibration. The camera is placed from the ground
truth's floor points, as a user places a real camera: each box's bottom centre against its
world position, cv2.solvePnP for a pinhole camera with square pixels and a centred principal
point, f the one of a scan (800-1600 px) with the smallest median reprojection error.

"before": the detector as it was (no learning from live frames, no shadow detection, no
exposure correction or relearning; the marker without the camera); "after": the defaults.
Printed per detector: person detections, huge blobs (> 10 % of the frame: no single person at
14-39 m covers 2 %), whole-frame blobs (box over half the frame), "robot" detections (there is
no robot), and precision and recall of the person boxes against the ground truth's boxes at
IoU >= 0.5 over gt frames 31-400 (the frames detected in; a box matching an ignored gt box,
conf 0, is neither). For the record only: nothing here tunes a setting.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from core.localization import NetworkCamera
from core.localization.detect import MarkerDetectorConfig, PersonDetector
from core.localization.detections import detect_frame
from server.node.config import DEFAULT_MARKER_COLOUR, DEFAULT_MARKER_HEIGHT, DEFAULT_MARKER_RADIUS

BACKGROUND_FRAMES = 30  # the node's default background_frames
HUGE = 0.10
WHOLE = 0.50
IOU = 0.5


def load_gt(path: str) -> np.ndarray:
    """Return the ground truth rows (frame, id, left, top, width, height, conf, x, y, z)."""
    return np.loadtxt(path, delimiter=",", ndmin=2)


def place_camera(gt: np.ndarray, size: tuple[int, int]) -> tuple[NetworkCamera, float, float]:
    """Return the camera placed from the gt floor points, its focal length (px) and median
    reprojection error (px)."""
    keep = gt[:, 6] > 0
    pix = np.column_stack([gt[keep, 2] + gt[keep, 4] / 2, gt[keep, 3] + gt[keep, 5]])
    world = np.column_stack([gt[keep, 7], gt[keep, 8], np.zeros(keep.sum())])
    w, h = size
    best = None
    for f in np.arange(800.0, 1601.0, 10.0):
        K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
        ok, rvec, tvec = cv2.solvePnP(world, pix, K, None, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            continue
        rvec, tvec = cv2.solvePnPRefineLM(world, pix, K, None, rvec, tvec)
        proj = cv2.projectPoints(world, rvec, tvec, K, None)[0].reshape(-1, 2)
        err = float(np.median(np.linalg.norm(proj - pix, axis=1)))
        if best is None or err < best[0]:
            best = (err, f, K, rvec, tvec)
    assert best is not None
    err, f, K, rvec, tvec = best
    R = cv2.Rodrigues(rvec)[0]
    return NetworkCamera(K, np.zeros(5), R, tvec.ravel(), size, "View_001"), f, err


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the IoU (N, M) of boxes a (N, 4) and b (M, 4), (x0, y0, x1, y1)."""
    x0 = np.maximum(a[:, None, 0], b[None, :, 0])
    y0 = np.maximum(a[:, None, 1], b[None, :, 1])
    x1 = np.minimum(a[:, None, 2], b[None, :, 2])
    y1 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return inter / (area_a[:, None] + area_b[None, :] - inter)


@dataclass
class Tally:
    persons: int = 0
    huge: int = 0
    whole: int = 0
    robots: int = 0
    tp: int = 0
    fp: int = 0
    fn: int = 0

    def score(self, boxes: np.ndarray, gt_frame: np.ndarray) -> None:
        """Count one frame's person boxes (N, 4) x0, y0, x1, y1 against its gt rows."""
        g = np.column_stack(
            [
                gt_frame[:, 2],
                gt_frame[:, 3],
                gt_frame[:, 2] + gt_frame[:, 4],
                gt_frame[:, 3] + gt_frame[:, 5],
            ]
        )
        counted = gt_frame[:, 6] > 0
        if len(boxes) and len(g):
            m = iou(boxes, g)
            rows, cols = linear_sum_assignment(-m)
            good = m[rows, cols] >= IOU
            rows, cols = rows[good], cols[good]
        else:
            rows = cols = np.zeros(0, dtype=int)
        matched_det = np.zeros(len(boxes), bool)
        matched_det[rows] = True
        hit = np.zeros(len(g), bool)
        hit[cols] = True
        self.tp += int(np.count_nonzero(hit & counted))
        self.fn += int(np.count_nonzero(~hit & counted))
        # A box on an ignored person is neither right nor wrong.
        on_ignored = np.zeros(len(boxes), bool)
        on_ignored[rows[~counted[cols]]] = True
        if len(boxes) and np.any(~counted):
            on_ignored |= iou(boxes, g[~counted]).max(axis=1) >= IOU
        self.fp += int(np.count_nonzero(~matched_det & ~on_ignored))


def run(video: str, gt: np.ndarray, camera: NetworkCamera, after: bool) -> Tally:
    """Return the tally of one pass over the clip with the detector before or after."""
    if after:
        people = PersonDetector()
        marker = MarkerDetectorConfig(colour=DEFAULT_MARKER_COLOUR, radius=DEFAULT_MARKER_RADIUS)
    else:
        people = PersonDetector(
            still_frames=None, shadows=False, gain_tolerance=None, relearn_fraction=1.0
        )
        # The marker without its radius: no size check.
        marker = MarkerDetectorConfig(colour=DEFAULT_MARKER_COLOUR)
    cap = cv2.VideoCapture(video)
    tally = Tally()
    k = 0
    while True:
        ok, image = cap.read()
        if not ok:
            break
        if k < BACKGROUND_FRAMES:
            people.learn(image)
        else:
            found = detect_frame(
                image,
                marker=marker,
                marker_height=DEFAULT_MARKER_HEIGHT,
                people=people,
                camera=camera,
            )
            boxes = []
            for d in found:
                if d.kind == "robot":
                    tally.robots += 1
                    continue
                tally.persons += 1
                assert d.bbox is not None
                x, y, w, h = d.bbox
                if w * h > WHOLE * image.shape[0] * image.shape[1]:
                    tally.whole += 1
                boxes.append((x, y, x + w, y + h))
            tally.huge += sum(
                1
                for d in found
                if d.kind == "person" and d.bbox is not None and _area_share(d, image) > HUGE
            )
            gt_frame = gt[gt[:, 0] == k + 1]
            if k + 1 <= 400:
                tally.score(np.array(boxes, dtype=float).reshape(-1, 4), gt_frame)
        k += 1
    cap.release()
    return tally


def _area_share(d, image) -> float:
    return d.bbox[2] * d.bbox[3] / (image.shape[0] * image.shape[1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("video")
    ap.add_argument("gt")
    args = ap.parse_args(argv)
    cap = cv2.VideoCapture(args.video)
    size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    cap.release()
    gt = load_gt(args.gt)
    camera, f, err = place_camera(gt, size)
    print(
        f"camera placed from {int((gt[:, 6] > 0).sum())} floor points: f = {f:.0f} px, "
        f"median reprojection {err:.2f} px, height {camera.center[2]:.2f} m"
    )
    for name, after in (("before", False), ("after", True)):
        t = run(args.video, gt, camera, after)
        prec = t.tp / max(t.tp + t.fp, 1)
        rec = t.tp / max(t.tp + t.fn, 1)
        print(
            f"{name:>6}: persons {t.persons}, huge blobs {t.huge}, whole-frame {t.whole}, "
            f"robot {t.robots}; gt frames 31-400: precision {prec:.3f} recall {rec:.3f} "
            f"(tp {t.tp} fp {t.fp} fn {t.fn})"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
