"""Benchmark: when does one image of a signpost decide between the two poses of its rings,
and is it right when it says it does?

Run from the repository root: `python -m bench.bench_landmark_ambiguity [--views 10]
[--seed 0] [--distances 2 3 4 5]`.

A circle seen in perspective has two poses that project it onto the same ellipse (the two-fold
ambiguity of spec 04 sec. 4). What tells them apart in one image is the interior: the image of
the circle's centre (the pencil centre of the two concentric rings) falls at a different pixel
under each pose, and, once the modules are large enough, the QR symbol's square. For a 20 cm
signpost at 5 m the two centres are a fraction of a pixel apart, so nothing in the image can pick
one. core.landmarks.detect_landmarks gives each pose its probability given the image
(core.landmarks.ambiguity) and says whether the image decides (`det.decided`: the reported pose
at least DECIDED_PROBABILITY); this benchmark counts how often each happens.

Views: the project's own signpost artwork (20 cm, core.landmarks.artwork) rendered by the twin's
landmark renderer (core.sim.render.landmarks: 640x480, f = 600 px, barrel distortion, the
landmark scenarios' sensor noise) at distances 2, 3, 4, 5 m (+-5 %) and obliquities in 15 deg
bins of 0-60 deg, tilted about a random in-plane axis, at a random pixel of the central 70 % of
the image. The head camera's intrinsics come from its own calibration (core.sim.intrinsics);
no truth reaches the detector (no `up` either: the image alone). Per view:

* err: the reported normal's angle to the true one (deg); a flip: err > 15 deg;
* right: decided and not a flip; wrong: decided and a flip (a wrong pose reported with a good
  pose's confidence); undecided: the image cannot decide, and then whether the truth is among
  the two hypotheses (a hypothesis' normal within 15 deg) and whether the covering covariance
  the detection reports covers the truth's normal (within 3 of its standard deviations across
  the normal);
* sep: the image distance (px) between the ring centres the two hypotheses predict (the poles
  of their vanishing lines with respect to the outer ring's conic, fitted to the detection's
  outline): the image evidence that separates them.

Anchor: an AprilTag 36h11 of the same outer size at the same pose and noise, found by cv2.aruco
and located by cv2.solvePnPGeneric(SOLVEPNP_IPPE_SQUARE), which returns both poses of a square
with their reprojection errors: "ambiguous" is the usual ratio test (best error / second error
> 0.2, the rule FRC's PhotonVision and WPILib apply); its flips, and its flips among the views
the ratio test calls unambiguous (the tag's "decided wrong").

Prints one row per (distance, obliquity) bin and the totals with the decided-wrong rate's 95 %
upper bound (Clopper-Pearson).
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
from core.landmarks.ambiguity import DECIDED_PROBABILITY
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
    x, y = undistort_points(det.outline, K, dist).T
    A = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])
    a, b, c, d, e, f = np.linalg.svd(A)[2][-1]
    Q = np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]])
    poles = []
    for n in (h.normal for h in det.hypotheses):
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


def _upper95(k: int, n: int) -> float:
    """Return the one-sided 95 % Clopper-Pearson upper bound (%) of a rate of k in n."""
    if n == 0:
        return float("nan")
    if k >= n:
        return 100.0
    from scipy.stats import beta

    return 100.0 * float(beta.ppf(0.95, k + 1, n - k))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=10, help="views per (distance, obliquity) bin")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--distances", type=float, nargs="+", default=list(DISTANCES))
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
        f"bin, seed {args.seed}; head camera from its own calibration ({cal.source}); decided "
        f"at p >= {DECIDED_PROBABILITY}"
    )
    head = (
        f"{'d m':>4} {'obl deg':>8} | {'loc':>4} {'right':>5} {'wrong':>5} {'undec':>5} "
        f"{'truth in':>8} {'covered':>7} {'flip%':>6} {'p95 err':>8} {'med sep':>8} | "
        f"{'tag loc':>7} {'flip%':>6} {'ambig%':>7} {'wrong':>5}"
    )
    print(head)
    print("-" * len(head))
    total = {"right": 0, "wrong": 0, "undecided": 0, "truth_in": 0, "covered": 0, "tag": 0}
    tag_total = {"located": 0, "flips": 0, "ambiguous": 0, "wrong": 0}
    for d0 in args.distances:
        for lo, hi in OBLIQUITY:
            errs, seps = [], []
            right = wrong = undecided = truth_in = covered = 0
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
                if hits and len(hits[0].hypotheses) == 2:
                    det = hits[0]
                    err = _angle(det.normal, T[:3, 2])
                    errs.append(err)
                    seps.append(_pole_separation(det, K, dist))
                    if det.decided:
                        right += err <= FLIP_DEG
                        wrong += err > FLIP_DEG
                    else:
                        undecided += 1
                        truth_in += any(
                            _angle(h.normal, T[:3, 2]) <= FLIP_DEG for h in det.hypotheses
                        )
                        covered += err <= 3 * _claimed_normal_std(det)
                tag_view = render_landmarks(cam, [(tag, T)], noise=NOISE, rng=seed)
                got = _tag(tag_view.image, T, K, dist)
                if got is not None:
                    tag_err.append(got[0])
                    tag_amb.append(got[1] > 0.2)
            n = len(errs)
            tag_flip = [e > FLIP_DEG for e in tag_err]
            tag_wrong = sum(f and not a for f, a in zip(tag_flip, tag_amb, strict=True))
            for key, v in (
                ("right", right),
                ("wrong", wrong),
                ("undecided", undecided),
                ("truth_in", truth_in),
                ("covered", covered),
            ):
                total[key] += v
            tag_total["located"] += len(tag_err)
            tag_total["flips"] += sum(tag_flip)
            tag_total["ambiguous"] += sum(tag_amb)
            tag_total["wrong"] += tag_wrong

            def pct(xs: list[bool]) -> str:
                return f"{100.0 * sum(xs) / len(xs):.0f}" if xs else "-"

            print(
                f"{d0:>4.0f} {f'{lo:.0f}-{hi:.0f}':>8} | {n:>4} {right:>5} {wrong:>5} "
                f"{undecided:>5} {f'{truth_in}/{undecided}':>8} {f'{covered}/{undecided}':>7} "
                f"{pct([e > FLIP_DEG for e in errs]):>6} "
                f"{(np.percentile(errs, 95) if errs else float('nan')):>8.1f} "
                f"{(np.median(seps) if seps else float('nan')):>8.2f} | "
                f"{len(tag_err):>7} {pct(tag_flip):>6} {pct(tag_amb):>7} {tag_wrong:>5}"
            )
    decided = total["right"] + total["wrong"]
    n_all = decided + total["undecided"]
    print()
    print(
        f"signpost: {n_all} located; decided {decided} (right {total['right']}, wrong "
        f"{total['wrong']}: {100.0 * total['wrong'] / max(decided, 1):.1f} % of decided, 95 % "
        f"upper bound {_upper95(total['wrong'], decided):.1f} %); undecided "
        f"{total['undecided']} (truth among the two: {total['truth_in']}, covered by the "
        f"reported covariance: {total['covered']})"
    )
    tl, tw = tag_total["located"], tag_total["wrong"]
    unamb = tl - tag_total["ambiguous"]
    print(
        f"AprilTag: {tl} located; flips {tag_total['flips']}; ambiguous by the ratio test "
        f"{tag_total['ambiguous']}; unambiguous {unamb}, of which flipped {tw} "
        f"({100.0 * tw / max(unamb, 1):.1f} %, 95 % upper bound {_upper95(tw, unamb):.1f} %)"
    )


if __name__ == "__main__":
    main()
