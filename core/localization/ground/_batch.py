"""Running a ground estimator over a batch: in chunks, with invalid targets masked, the
reprojection RMS added, and the typed error raised for a single target that was not located."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from core.errors import DegenerateConfiguration, NotEnoughPoints
from core.geometry.camera import project_points
from core.localization.ground._estimate import FloorEstimate, Method, PointStatus
from core.localization.ground._observations import Observations

Array = NDArray[np.float64]

# Targets per pass of the vectorised estimators (see run_estimator).
_CHUNK = 1 << 15


# Raw output of an estimator on a chunk: point (b, 3), point_cov (b, 3, 3), status (b,),
# cameras used (b,), iterations.
Raw = tuple[Array, Array, NDArray[np.int8], NDArray[np.int64], int]


def run_estimator(
    obs: Observations,
    method: Method,
    height: float | None,
    min_cameras: int,
    solve: Callable[[Observations], Raw],
) -> FloorEstimate:
    """Run `solve` over the batch in chunks, mask invalid targets, add the reprojection RMS,
    and raise the typed error for a single target that could not be located.

    Chunks of `_CHUNK` targets keep the working arrays in the CPU cache: on 10^6 targets this
    is ~1.5x faster than one pass, and no slower on small batches.
    """
    parts = []
    iterations = 0
    for sub in obs.chunks(_CHUNK):
        point, point_cov, status, n_cam, its = solve(sub)
        iterations = max(iterations, its)
        ok = status == PointStatus.OK
        point = np.where(ok[:, None], point, np.nan)
        point_cov = np.where(ok[:, None, None], point_cov, np.nan)
        idx = np.flatnonzero(ok)
        sq = np.zeros(idx.size)
        for k, cam in enumerate(sub.cameras):
            uv = project_points(point[idx], cam.rvec, cam.t, cam.K, cam.dist).points
            e = uv - sub.pixels[k, idx]
            sq += np.where(sub.visible[k, idx], e[:, 0] ** 2 + e[:, 1] ** 2, 0.0)
        rms = np.full(sub.n_points, np.nan)
        rms[idx] = np.sqrt(sq / (2.0 * n_cam[idx]))
        parts.append((point, point_cov, status, n_cam, rms))
    if len(parts) == 1:
        point, point_cov, status, n_cam, rms = parts[0]
    else:
        point, point_cov, status, n_cam, rms = (np.concatenate(a) for a in zip(*parts, strict=True))
    if not obs.batched:
        _raise_for(method, PointStatus(int(status[0])), int(n_cam[0]), min_cameras)
        return FloorEstimate(
            method, height, point[0], point_cov[0], status[0], n_cam[0], rms[0], iterations
        )
    return FloorEstimate(method, height, point, point_cov, status, n_cam, rms, iterations)


def _raise_for(method: Method, status: PointStatus, n_cam: int, min_cameras: int) -> None:
    if status == PointStatus.TOO_FEW_CAMERAS:
        raise NotEnoughPoints(
            f"the target is seen by {n_cam} camera(s); the {method} estimator needs at least "
            f"{min_cameras}. Add a detection from another camera or use a monocular estimate."
        )
    if status == PointStatus.DEGENERATE:
        raise DegenerateConfiguration(
            f"the {method} estimator cannot fix the target: its viewing rays are parallel to the "
            "plane Z = h (a pixel on the horizon) or to each other (cameras in line with the "
            "target). Use detections from cameras that see the target from different directions."
        )
    if status == PointStatus.BEHIND_CAMERA:
        raise DegenerateConfiguration(
            f"the {method} solution lies behind a camera: a pixel's ray does not meet the plane "
            "Z = h in front of the camera (a pixel above the horizon, or the wrong height h), or "
            "the detections do not belong to the same target."
        )
