"""Landmark detection, pose and decoding in a 1280x720 frame, beside zxing-cpp and OpenCV.

Run from the repository root: python -m bench.bench_landmarks
Two rendered frames (core.sim.render.landmarks: 900 px focal length, barrel distortion, the
twin's default sensor noise), each with four object marks (10 cm) and two signposts (20 cm):
  * near: 0.6-0.9 m, 20-50 deg obliquity, modules of 1.5-3 px (readable);
  * far: 1.5-3 m, the patterns located but their modules under 1 px.
For each frame: core.landmarks.detect_landmarks (every landmark found, located with its
covariance, its symbol read on the rectified patch), zxingcpp.read_barcodes on the raw frame
and cv2.QRCodeDetector.detectAndDecodeMulti on the raw frame (zxing-cpp with its defaults), best
of 30 single-threaded runs, the three interleaved round by round so that their ratios share the
machine's load, and the median over the rounds of each round's ratio, in wall time and in CPU
time (this thread's: less disturbed on a loaded machine); with what each found and
read and its error against the rendering's truth: the corners it reports (the frames' outer
corners for detect_landmarks, the symbols' corners for the QR readers; RMS pixels, median over
the landmarks), and detect_landmarks' pose (position error in % of the distance, normal error
in degrees, medians). Spec 04's goal: detection and pose of all landmarks in <= 33 ms on one
core.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from functools import partial

# One core: numpy's BLAS threads too (before numpy loads).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2
import numpy as np
import zxingcpp

from bench._common import best_of, print_table
from core.geometry.rotations import rotvec_to_matrix
from core.landmarks import ObjectMark, Signpost
from core.landmarks.artwork import make_artwork, pattern_layout
from core.landmarks.detect import detect_landmarks
from core.sim.render import SensorNoise
from core.sim.render.landmarks import (
    LandmarkCamera,
    LandmarkView,
    artwork_texture,
    render_landmarks,
)

CAM = LandmarkCamera(
    np.array([[900.0, 0, 640.5], [0, 900.0, 360.0], [0, 0, 1]]),
    np.array([-0.1, 0.03, 0.0005, -0.0003, 0.0]),
    1280,
    720,
)
ARTS = [
    make_artwork(ObjectMark(i, c, f"{c} {i}", "kitchen", (0.08, 0.08, 0.1)))
    for i, c in enumerate(("cup", "medicine box", "remote", "kettle"))
] + [
    make_artwork(Signpost(20 + i, f"door {i}", "hall", (1.0, 2.0, 1.2, 0, 0, 0, 1), (1, 2)))
    for i in range(2)
]


def frame(distances: tuple[float, float], seed: int) -> LandmarkView:
    """Return a 1280x720 frame with the six landmarks on a 3 x 2 grid of the field of view, and
    their truth."""
    rng = np.random.default_rng(seed)
    placements = []
    grid = [(x, y) for y in (-0.2, 0.2) for x in (-0.45, 0.0, 0.45)]
    for k, art in enumerate(ARTS):
        d = rng.uniform(*distances)
        T = np.eye(4)
        axis = rng.uniform(0, 2 * np.pi)
        obl = np.radians(rng.uniform(20, 50))
        T[:3, :3] = (
            rotvec_to_matrix(obl * np.array([np.cos(axis), np.sin(axis), 0]))
            @ rotvec_to_matrix([np.pi, 0, 0])
            @ rotvec_to_matrix([0, 0, rng.uniform(-np.pi, np.pi)])
        )
        ray = np.array([*grid[k], 1.0])
        T[:3, 3] = d * ray / np.linalg.norm(ray)
        placements.append((artwork_texture(art), T, art.size, art.module_mm / 1000))
    return render_landmarks(CAM, placements, noise=SensorNoise(), rng=seed)


def interleaved(
    calls: dict[str, Callable[[], object]], rounds: int = 30
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Return each call's wall times and CPU times (this thread's, seconds) over `rounds` rounds
    that run every call once in turn, so that all of them see the same load on a shared
    machine (CPU time is the less disturbed by other processes on a loaded one)."""
    wall: dict[str, list[float]] = {name: [] for name in calls}
    cpu: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(rounds):
        for name, fn in calls.items():
            c0 = time.thread_time()
            wall[name].append(best_of(fn, repeats=1))
            cpu[name].append(time.thread_time() - c0)
    return wall, cpu


def _corner_rms(found: np.ndarray, truth: np.ndarray) -> float:
    """Return the RMS distance (pixels) of four corners to the true ones, over the eight ways
    of matching two squares' corners (the readers' corner order differs)."""
    best = np.inf
    for order in (truth, truth[::-1]):
        for k in range(4):
            d = found - np.roll(order, k, 0)
            best = min(best, float(np.sqrt(np.mean(np.sum(d * d, 1)))))
    return best


def _symbol_corners(T: np.ndarray, side: float) -> np.ndarray:
    """Return the distorted pixels (4, 2) of the corners of a square symbol of `side` metres
    at the centre of the mark T_cam_mark."""
    sq = 0.5 * side * np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    uv, _ = cv2.projectPoints(sq, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], CAM.K, CAM.dist)
    return np.asarray(uv.reshape(4, 2), dtype=np.float64)


def errors(view: LandmarkView, dets: list, zx: list, cv_pts: list) -> dict[str, dict[str, str]]:
    """Return each method's error columns against the view's truth."""
    truths = view.truth
    qr = {i: pattern_layout(a.kind, a.size).qr_side for i, a in enumerate(ARTS)}
    index = {a.text: i for i, a in enumerate(ARTS)}
    pos: list[float] = []
    normal: list[float] = []
    corners: list[float] = []
    for d in dets:
        # The truth nearest the detection's centre.
        k = int(np.argmin([np.linalg.norm(t.T_cam_mark[:3, 3] - d.position) for t in truths]))
        T = truths[k].T_cam_mark
        pos.append(100 * float(np.linalg.norm(d.position - T[:3, 3]) / np.linalg.norm(T[:3, 3])))
        cos = float(np.clip(d.normal @ T[:3, 2], -1.0, 1.0))
        normal.append(float(np.degrees(np.arccos(cos))))
        if d.kind == "object":
            corners.append(_corner_rms(d.outline, truths[k].corners))
    zx_err = [
        _corner_rms(
            np.array(
                [
                    [p.x, p.y]
                    for p in (
                        r.position.top_left,
                        r.position.top_right,
                        r.position.bottom_right,
                        r.position.bottom_left,
                    )
                ],
                float,
            ),
            _symbol_corners(truths[index[r.text]].T_cam_mark, qr[index[r.text]]),
        )
        for r in zx
        if r.text in index
    ]
    cv_err = [
        _corner_rms(p, _symbol_corners(truths[index[t]].T_cam_mark, qr[index[t]]))
        for t, p in cv_pts
        if t in index
    ]

    def med(v: list[float], fmt: str) -> str:
        return format(float(np.median(v)), fmt) if v else "-"

    return {
        "detect_landmarks": {
            "corner px": med(corners, ".3f"),
            "pos %": med(pos, ".3f"),
            "normal deg": med(normal, ".2f"),
        },
        "zxingcpp raw": {"corner px": med(zx_err, ".3f")},
        "cv2.QRCodeDetector raw": {"corner px": med(cv_err, ".3f")},
    }


def main() -> None:
    cv2.setNumThreads(1)
    qr = cv2.QRCodeDetector()
    texts = {a.text for a in ARTS}
    for name, distances in (("near", (0.6, 0.9)), ("far", (1.5, 3.0))):
        view = frame(distances, 1)
        img = view.image
        dets = detect_landmarks(img, CAM.K, CAM.dist)
        zx = zxingcpp.read_barcodes(img)
        ok, cv_texts, cv_corners, _ = qr.detectAndDecodeMulti(img)
        cv_read = [
            (t, np.asarray(p, float).reshape(4, 2))
            for t, p in zip(cv_texts if ok else (), cv_corners if ok else (), strict=True)
        ]
        err = errors(view, dets, zx, cv_read)
        calls: dict[str, Callable[[], object]] = {
            "detect_landmarks": partial(detect_landmarks, img, CAM.K, CAM.dist),
            "zxingcpp raw": partial(zxingcpp.read_barcodes, img),
            "cv2.QRCodeDetector raw": partial(qr.detectAndDecodeMulti, img),
        }
        times, cpu = interleaved(calls)
        anchor = np.array(times["zxingcpp raw"])
        cpu_anchor = np.array(cpu["zxingcpp raw"])
        found = {
            "detect_landmarks": (len(dets), sum(d.text in texts for d in dets)),
            "zxingcpp raw": (len(zx), sum(r.text in texts for r in zx)),
            "cv2.QRCodeDetector raw": (None, sum(t in texts for t, _ in cv_read)),
        }
        rows = []
        for method, (n_found, n_read) in found.items():
            extra = {
                "found": "" if n_found is None else f"{n_found}/{len(ARTS)}",
                "read": f"{n_read}/{len(ARTS)}",
                # Each round's ratio, then their median: the load shared within a round.
                "median ratio": f"{np.median(np.array(times[method]) / anchor):.2f}x",
                # The same from CPU time: best of the rounds, and the median of their ratios.
                "cpu ratio": f"{min(cpu[method]) / cpu_anchor.min():.2f}x",
                "cpu median": f"{np.median(np.array(cpu[method]) / cpu_anchor):.2f}x",
            }
            rows.append((method, min(times[method]), {**extra, **err[method]}))
        print_table(
            f"{name} frame 1280x720, six landmarks at {distances[0]}-{distances[1]} m "
            "(goal: detect_landmarks <= 33 ms)",
            rows,
            anchor="zxingcpp raw",
        )
        print()


if __name__ == "__main__":
    main()
