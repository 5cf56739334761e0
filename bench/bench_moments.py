"""Affine maps from image moments: accuracy under affine warps and growth with perspective.

Run from the repository root: python -m bench.bench_moments
A letter-like mask (~100 px tall on a 300 x 300 canvas, room for the
perspective warps) is warped with cv2.warpPerspective
(INTER_NEAREST) by H = T_c [[A, 0], [g^T, 1]] T_c^-1 about the shape's centre c, with
|g| chosen so that eps = max |g^T (x - c)| over the shape (the relative change of the
projective scale w across the region) takes the listed values. For each eps the table gives,
over random A and directions of g, the median and maximum of
  * vs LS affine: max transfer error over the region between the moment affine and the affine
    least-squares fit (cv2.estimateAffine2D, all inliers) to the known correspondences x -> H x
    of every region pixel, in px;
  * vs H: max transfer error over the region between the moment affine and H itself, in px;
  * LS affine vs H: the same for the least-squares affine, the floor any affine map has;
plus the time of mask moments and of the whole estimate.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from core.homography.moments import affine_from_moments, mask_moments
from tests.support.letters import LETTER_F, raster_polygon

SIZE = 300


def raster(poly: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Return a uint8 mask of the polygon translated to `centre` (1/16 px vertex precision)."""
    return raster_polygon(poly + centre, SIZE)


def random_affine(rng: np.random.Generator) -> np.ndarray:
    """Return a random 2x2 map: any rotation, anisotropic scale 0.75-1.25, shear up to 0.2."""
    th = rng.uniform(-np.pi, np.pi)
    c, s = np.cos(th), np.sin(th)
    S = np.diag(rng.uniform(0.75, 1.25, 2))
    return np.array([[c, -s], [s, c]]) @ S @ np.array([[1.0, rng.uniform(-0.2, 0.2)], [0, 1]])


def transfer(M: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ M[:, :2].T + M[:, 2]


def apply_h(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    h = np.column_stack([pts, np.ones(len(pts))]) @ H.T
    return h[:, :2] / h[:, 2:]


def main() -> None:
    rng = np.random.default_rng(0)
    centre = np.array([SIZE / 2.0, SIZE / 2.0])
    a = raster(LETTER_F, centre)
    ys, xs = np.nonzero(a)
    pix = np.column_stack([xs, ys]).astype(np.float64)
    radius = np.linalg.norm(pix - centre, axis=1).max()
    Tc = np.array([[1.0, 0.0, centre[0]], [0.0, 1.0, centre[1]], [0.0, 0.0, 1.0]])

    print(f"letter F, {len(pix)} px, 30 random warps per row")
    print(f"{'eps':>6} | {'vs LS affine (px)':>19} | {'vs H (px)':>17} | {'LS affine vs H':>17}")
    print(
        f"{'':>6} | {'median':>9} {'max':>9} | {'median':>8} {'max':>8} | {'median':>8} {'max':>8}"
    )
    for eps in (0.0, 0.01, 0.02, 0.05, 0.1, 0.2):
        e_ls, e_h, e_floor = [], [], []
        for _ in range(30):
            A = random_affine(rng)
            phi = rng.uniform(0, 2 * np.pi)
            g = eps / radius * np.array([np.cos(phi), np.sin(phi)])
            P = np.eye(3)
            P[:2, :2] = A
            P[2, :2] = g
            H = Tc @ P @ np.linalg.inv(Tc)
            b = cv2.warpPerspective(a, H, (SIZE, SIZE), flags=cv2.INTER_NEAREST)
            ours = affine_from_moments(a, b)
            truth = apply_h(H, pix)
            ls, _ = cv2.estimateAffine2D(
                pix.astype(np.float32), truth.astype(np.float32), ransacReprojThreshold=1e9
            )
            e_ls.append(np.abs(transfer(ours, pix) - transfer(ls, pix)).max())
            e_h.append(np.linalg.norm(transfer(ours, pix) - truth, axis=1).max())
            e_floor.append(np.linalg.norm(transfer(ls, pix) - truth, axis=1).max())
        print(
            f"{eps:6.2f} | {np.median(e_ls):9.2f} {np.max(e_ls):9.2f} | "
            f"{np.median(e_h):8.2f} {np.max(e_h):8.2f} | "
            f"{np.median(e_floor):8.2f} {np.max(e_floor):8.2f}"
        )

    b = cv2.warpAffine(a, np.hstack([random_affine(rng), [[0.0], [0.0]]]), (SIZE, SIZE))
    reps = 50
    t0 = time.perf_counter()
    for _ in range(reps):
        mask_moments(a)
    t_m = (time.perf_counter() - t0) / reps
    t0 = time.perf_counter()
    for _ in range(reps):
        cv2.moments(a, True)
    t_cv = (time.perf_counter() - t0) / reps
    t0 = time.perf_counter()
    for _ in range(reps):
        affine_from_moments(a, a)
    t_a = (time.perf_counter() - t0) / reps
    print(f"mask_moments {t_m * 1e3:.2f} ms, cv2.moments {t_cv * 1e3:.2f} ms (300x300 mask)")
    print(f"affine_from_moments {t_a * 1e3:.2f} ms (two masks)")


if __name__ == "__main__":
    main()
