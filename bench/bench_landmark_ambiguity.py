"""Benchmark: when can one image of a signpost decide between the two poses of its rings?

Run from the repository root: `python -m bench.bench_landmark_ambiguity [--views 10]
[--seed 0]`.

A circle seen in perspective has two poses that project it onto the same ellipse (the two-fold
ambiguity of spec 04 sec. 4). What tells them apart in one image is the interior: the image of
the circle's centre (the pencil centre of the two concentric rings) falls at a different pixel
under each pose, and, once the modules are large enough, the QR symbol's square. For a 20 cm
signpost at 5 m the two centres are a fraction of a pixel apart, so nothing in the image can pick
one; a detector should then say so rather than report one pose with a good pose's confidence.

Views: the project's own signpost artwork (20 cm, core.landmarks.artwork) rendered by the twin's
landmark renderer (core.sim.render.landmarks: 640x480, f = 600 px, barrel distortion, the
landmark scenarios' sensor noise) at distances 2, 3, 4, 5 m (+-5 %) and obliquities in 15 deg
bins of 0-60 deg, tilted about a random in-plane axis, at a random pixel of the central 70 % of
the image. The head camera's intrinsics come from its own calibration (core.sim.intrinsics);
no truth reaches the detector. Per view, for core.landmarks.detect_landmarks:

* err: the returned normal's angle to the true one (deg); flip: err > 15 deg;
* sep: the image distance (px) between the ring centres the returned pose and its
  `alternative` predict (the poles of their vanishing lines with respect to the outer ring's
  conic, fitted to the detection's outline: the image evidence that separates them, from the
  detector's own output on the calibrated K, dist, no truth);
* claimed: the returned covariance's standard deviation of the normal (deg, the root of the
  rotation block's two variances across the normal);
* overconfident: the two candidate normals are more than 3 claimed deviations apart while
  sep < 0.3 px, i.e. one pose is reported with a confidence the image cannot give;
* unwarned: flips whose error exceeds 3 claimed deviations (a wrong pose reported as good).

Anchor: an AprilTag 36h11 of the same outer size at the same pose and noise, found by cv2.aruco
and located by cv2.solvePnPGeneric(SOLVEPNP_IPPE_SQUARE), which returns both poses of a square
with their reprojection errors: "ambiguous" is the usual ratio test (best error / second error
> 0.2, the rule FRC's PhotonVision and WPILib apply), flips as above. (pupil-apriltags on PyPI
wraps the AprilTag 3 library with the same two-pose test; cv2.aruco, already a dependency,
gives the same detector family.)

Prints one row per (distance, obliquity) bin: views located, flips %, 95th percentile error,
median sep, % with sep < 0.3 px, flips among those, % overconfident, median claimed
deviation (deg), unwarned flips; the tag's located %, flips
% and ambiguous %.
"""

from __future__ import annotations

import argparse
import math

import cv2
import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.camera import left_jacobian_so3, undistort_points
from core.geometry.rotations import matrix_to_rotvec
from core.landmarks.artwork import make_artwork
from core.landmarks.detect import LandmarkDetection, detect_landmarks
from core.landmarks.payload import Signpost
from core.sim.intrinsics import NOISE, calibrate_from_board_views, facing
from core.sim.render.landmarks import artwork_texture, render_landmarks, tag_texture

Array = NDArray[np.float64]

K_TRUE = np.array([[600.0, 0.0, 321.5], [0.0, 600.0, 242.0], [0.0, 0.0, 1.0]])
DIST_TRUE = np.array([-0.12, 0.05, 0.001, -0.0005, 0.0])
SIZE = 0.20
DISTANCES = (2.0, 3.0, 4.0, 5.0)
OBLIQUITY = ((0.0, 15.0), (15.0, 30.0), (30.0, 45.0), (45.0, 60.0))
FLIP_DEG = 15.0
SEP_PX = 0.3
_ARUCO = cv2.aruco.ArucoDetector(
    cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), cv2.aruco.DetectorParameters()
)


def _place(rng: np.random.Generator, d: float, obl: float) -> Array | None:
    from core.sim.render.landmarks import LandmarkCamera

    cam = LandmarkCamera(K_TRUE, DIST_TRUE, 640, 480)
    u, v = rng.uniform(0.15, 0.85) * 640, rng.uniform(0.15, 0.85) * 480
    ray = np.append(undistort_points(np.array([u, v]), cam.K, cam.dist), 1.0)
    T = np.eye(4)
    T[:3, :3] = facing(math.radians(obl), rng.uniform(0, 2 * np.pi), rng.uniform(-np.pi, np.pi))
    T[:3, 3] = d * ray / np.linalg.norm(ray)
    return T


def _angle(a: Array, b: Array) -> float:
    return math.degrees(math.acos(float(np.clip(a @ b, -1.0, 1.0))))


def _pole_separation(det: LandmarkDetection, K: Array, dist: Array) -> float:
    """Return the distance (px) between the images of the ring centre the two candidate poses
    predict: the poles of their vanishing lines (l = n in normalised coordinates) with respect
    to the outer ring's conic, fitted (algebraically) to the detection's outline undistorted
    with the calibrated K, dist. Under the right pose the pole is where the rings' pencil
    centre is; this distance is all the evidence one image of the rings holds."""
    assert det.alternative is not None
    x, y = undistort_points(det.outline, K, dist).T
    A = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
    a, b, c, d, e, f = np.linalg.svd(A)[2][-1]
    Q = np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]])
    poles = []
    for n in (det.normal, det.alternative[:3, 2]):
        p = np.linalg.solve(Q, n)
        poles.append(p[:2] / p[2])
    return float(np.linalg.norm(poles[0] - poles[1]) * (K[0, 0] + K[1, 1]) / 2)


def _claimed_normal_std(det: LandmarkDetection) -> float:
    """Return the claimed standard deviation (deg) of the normal: the rotation-vector covariance
    turned into one of a left perturbation (d theta = J_l(rvec) d rvec), then the normal's,
    d n = d theta x n, as the root of half its trace (per direction across the normal)."""
    rvec = matrix_to_rotvec(det.T_cam_mark[:3, :3])
    J = left_jacobian_so3(rvec)
    cov_theta = J @ det.cov[:3, :3] @ J.T
    n = det.normal
    nx = np.array([[0.0, -n[2], n[1]], [n[2], 0.0, -n[0]], [-n[1], n[0], 0.0]])
    cov_n = nx @ cov_theta @ nx.T
    return math.degrees(math.sqrt(max(float(np.trace(cov_n)), 0.0) / 2))


def _tag(image: NDArray[np.uint8], T: Array, K: Array, dist: Array) -> tuple[float, float] | None:
    """Return (normal error deg, ambiguity ratio) of the tag, or None when not found."""
    corners, ids, _ = _ARUCO.detectMarkers(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
    if ids is None or 0 not in ids.ravel():
        return None
    c = corners[list(ids.ravel()).index(0)].reshape(4, 2).astype(np.float64)
    h = SIZE / 2
    obj = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], np.float64)
    n, rvecs, _, errs = cv2.solvePnPGeneric(obj, c, K, dist, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    if n < 1:
        return None
    e = np.asarray(errs, np.float64).ravel()
    order = np.argsort(e)
    R, _ = cv2.Rodrigues(rvecs[int(order[0])])
    ratio = float(e[order[0]] / e[order[1]]) if n > 1 and e[order[1]] > 0 else 0.0
    return _angle(np.asarray(R)[:, 2], T[:3, 2]), ratio


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=10, help="views per (distance, obliquity) bin")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    from core.sim.render.landmarks import LandmarkCamera

    cam = LandmarkCamera(K_TRUE, DIST_TRUE, 640, 480)
    cal = calibrate_from_board_views(cam, rng)
    K, dist = cal.K, cal.dist
    door = Signpost(3, "kitchen door", "kitchen", (2.5, 3.0, 1.4, 0.0, 0.0, 0.7071, 0.7071), (1, 4))
    tex = artwork_texture(make_artwork(door, size=SIZE))
    tag = tag_texture(SIZE)
    print(
        f"signpost {SIZE * 100:.0f} cm vs AprilTag 36h11, 640x480 f=600, {args.views} views per "
        f"bin, seed {args.seed}; head camera from its own calibration ({cal.source})"
    )
    head = (
        f"{'d m':>4} {'obl deg':>8} | {'loc':>4} {'flip%':>6} {'p95 err':>8} {'med sep':>8} "
        f"{'sep<0.3%':>9} {'flip|amb':>9} {'overconf%':>10} {'claimed':>8} {'unwarned':>8} | "
        f"{'tag loc':>7} {'flip%':>6} "
        f"{'ambig%':>7}"
    )
    print(head)
    print("-" * len(head))
    all_sep: list[float] = []
    all_flip: list[bool] = []
    for d0 in DISTANCES:
        for lo, hi in OBLIQUITY:
            errs, seps, flips, over, claims, unwarned = [], [], [], [], [], []
            tag_err, tag_amb = [], []
            made = 0
            while made < args.views:
                d = d0 * rng.uniform(0.95, 1.05)
                T = _place(rng, d, rng.uniform(lo, hi))
                if T is None:
                    continue
                made += 1
                seed = int(rng.integers(2**31))
                try:
                    view = render_landmarks(cam, [(tex, T, SIZE, None)], noise=NOISE, rng=seed)
                except InvalidInput:  # a placement the renderer refuses is drawn again
                    made -= 1
                    continue
                dets = detect_landmarks(view.image, K, dist, ring_size=SIZE)
                hits = [
                    x
                    for x in dets
                    if x.kind == "signpost" and np.linalg.norm(x.position - T[:3, 3]) < 0.1 * d
                ]
                if hits and hits[0].alternative is not None:
                    det = hits[0]
                    assert det.alternative is not None
                    err = _angle(det.normal, T[:3, 2])
                    sep = _pole_separation(det, K, dist)
                    split = _angle(det.normal, det.alternative[:3, 2])
                    claimed = _claimed_normal_std(det)
                    errs.append(err)
                    seps.append(sep)
                    flips.append(err > FLIP_DEG)
                    over.append(sep < SEP_PX and split > 3 * claimed)
                    claims.append(claimed)
                    unwarned.append(err > FLIP_DEG and err > 3 * claimed)
                tag_view = render_landmarks(cam, [(tag, T)], noise=NOISE, rng=seed)
                got = _tag(tag_view.image, T, K, dist)
                if got is not None:
                    tag_err.append(got[0])
                    tag_amb.append(got[1] > 0.2)
            all_sep += seps
            all_flip += flips
            amb = [f for f, s in zip(flips, seps, strict=True) if s < SEP_PX]
            n = len(errs)

            def pct(xs: list[bool]) -> str:
                return f"{100.0 * sum(xs) / len(xs):.0f}" if xs else "-"

            print(
                f"{d0:>4.0f} {f'{lo:.0f}-{hi:.0f}':>8} | {n:>4} {pct(flips):>6} "
                f"{(np.percentile(errs, 95) if errs else float('nan')):>8.1f} "
                f"{(np.median(seps) if seps else float('nan')):>8.2f} "
                f"{pct([s < SEP_PX for s in seps]):>9} "
                f"{(f'{sum(amb)}/{len(amb)}' if amb else '-'):>9} {pct(over):>10} "
                f"{(np.median(claims) if claims else float('nan')):>8.2f} {sum(unwarned):>8} | "
                f"{len(tag_err):>7} {pct([e > FLIP_DEG for e in tag_err]):>6} {pct(tag_amb):>7}"
            )
    s = np.array(all_sep)
    f = np.array(all_flip)
    print()
    print("flip rate against the centres' separation (all bins):")
    for a, b in ((0.0, 0.1), (0.1, 0.3), (0.3, 1.0), (1.0, np.inf)):
        m = (s >= a) & (s < b)
        rate = f"{100.0 * f[m].mean():.0f} %" if m.any() else "-"
        print(f"  sep {a:.1f}-{b:.1f} px: {int(m.sum()):>4} views, flips {rate}")


if __name__ == "__main__":
    main()
