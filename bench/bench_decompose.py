"""Batch homography decomposition against cv2.decomposeHomographyMat called in a Python loop.

Run from the repository root: python -m bench.bench_decompose [B]
Prints the best-of-N wall time of each, their ratio, and the largest difference between the two
candidate sets (every one of ours matched to one of OpenCV's) on the first 1000 homographies.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

import cv2
import numpy as np

from core.geometry.rotations import rotvec_to_matrix
from core.homography.decompose import decompose_homography_batch


def best_of(fn: Callable[[], object], repeats: int) -> float:
    """Return the smallest wall time of `repeats` calls of fn, in seconds."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def random_homographies(B: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Return B random plane-induced pixel homographies (B, 3, 3) and their shared K."""
    rng = np.random.default_rng(seed)
    K = np.array([[800.0, 0.0, 320.0], [0.0, 790.0, 240.0], [0.0, 0.0, 1.0]])
    R = rotvec_to_matrix(rng.normal(size=(B, 3)) * 0.5)
    n = rng.normal(size=(B, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t = rng.normal(size=(B, 3)) * 0.4
    # Keep both camera centres on the same side of the plane (d2 / d = 1 + n^T R^T t > 0).
    side = 1.0 + np.einsum("bi,bji,bj->b", n, R, t)
    t[side < 0.1] *= -0.2
    He = R + t[:, :, None] * n[:, None, :]
    return K @ He @ np.linalg.inv(K), K


def main() -> None:
    B = int(sys.argv[1]) if len(sys.argv) > 1 else 10_000
    H, K = random_homographies(B)

    def ours() -> object:
        return decompose_homography_batch(H, K)

    def opencv() -> object:
        return [cv2.decomposeHomographyMat(h, K) for h in H]

    t_ours = best_of(ours, 7)
    t_cv = best_of(opencv, 3)
    print(f"B = {B} homographies")
    print(f"  decompose_homography_batch          {t_ours * 1e3:8.2f} ms")
    print(f"  cv2.decomposeHomographyMat (loop)   {t_cv * 1e3:8.2f} ms")
    print(f"  speed-up                            {t_cv / t_ours:8.2f} x")

    res = decompose_homography_batch(H[:1000], K)
    worst = 0.0
    for b in range(len(res.R)):
        _, Rs, ts, ns = cv2.decomposeHomographyMat(H[b], K)
        for k in np.nonzero(res.valid[b])[0]:
            worst = max(
                worst,
                min(
                    max(
                        np.abs(res.R[b, k] - Rc).max(),
                        np.abs(res.t[b, k] - tc.ravel()).max(),
                        np.abs(res.n[b, k] - nc.ravel()).max(),
                    )
                    for Rc, tc, nc in zip(Rs, ts, ns, strict=True)
                ),
            )
    print(f"  max |ours - OpenCV| (first 1000)    {worst:8.1e}")


if __name__ == "__main__":
    main()
