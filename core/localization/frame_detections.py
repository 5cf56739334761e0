"""One camera frame's detections as the tracker takes them (core.localization.tracking): the
checks of what a caller hands over (pixels, covariances, heights, kinds, labels, looks), and
each detection's pixel covariance with the camera's calibration error added, with how well
it places the body on the floor."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.localization._projection import project_plane, transposed
from core.localization.association import largest_variance
from core.localization.cameras import NetworkCamera
from core.localization.ground import locate_monocular
from core.localization.tracks import KINDS

Array = NDArray[np.float64]


def _as_covariances(cov: ArrayLike, n: int, name: str) -> Array:
    try:
        c = np.array(cov, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be numeric, shape ({n}, 2, 2): {exc}") from None
    if c.shape == (2, 2):
        c = np.broadcast_to(c, (n, 2, 2)).copy()
    if c.shape != (n, 2, 2):
        raise InvalidInput(f"{name} must have shape ({n}, 2, 2) or (2, 2), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise InvalidInput(f"{name} contains NaN or infinite values")
    det = c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] * c[:, 1, 0]
    asym = np.abs(c[:, 0, 1] - c[:, 1, 0]) > 1e-9 * np.sqrt(np.abs(c[:, 0, 0] * c[:, 1, 1]))
    if np.any(c[:, 0, 0] <= 0) or np.any(det <= 0) or np.any(asym):
        raise InvalidInput(f"every {name} matrix must be symmetric positive definite")
    return c


def _as_strings(
    values: Sequence[str | None] | str | None, n: int, name: str, allowed: tuple[str, ...] = ()
) -> list[str | None]:
    if values is None:
        return [None] * n
    if isinstance(values, str):
        values = [values] * n
    if len(values) != n:
        raise InvalidInput(f"{name} must hold {n} values, one per detection, got {len(values)}")
    out: list[str | None] = []
    for v in values:
        if v is not None and not isinstance(v, str):
            raise InvalidInput(f"{name} must be strings or None, got {type(v).__name__}")
        if allowed and v is not None and v not in allowed:
            raise InvalidInput(f"{name} must be one of {', '.join(allowed)}, got {v!r}")
        out.append(v)
    return out


def as_looks(appearances: ArrayLike | None, n: int) -> Array | None:
    """Return the detections' appearance descriptors as (n, F) finite non-negative floats,
    or None when none were given."""
    if appearances is None:
        return None
    try:
        look = np.array(appearances, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"appearances must be numeric, shape (D, F): {exc}") from None
    if look.size == 0 and n == 0:
        return None
    if look.ndim != 2 or look.shape[0] != n:
        raise InvalidInput(f"appearances must have shape ({n}, F), one row per pixel")
    if not np.all(np.isfinite(look)) or np.any(look < 0):
        raise InvalidInput("appearances are histograms: finite and non-negative")
    return look


def parse_frame(
    pixels: ArrayLike,
    pixel_cov: ArrayLike | None,
    heights: ArrayLike,
    kinds: Sequence[str | None] | str | None,
    labels: Sequence[str | None] | str | None,
    pixel_sigma: float,
) -> tuple[Array, Array, Array, list[str], list[str | None]]:
    """Return one frame's detections checked (see Tracker.update): pixels (D, 2), their
    covariances (D, 2, 2), heights (D,), kinds (None read as "unknown") and labels; raise
    InvalidInput on anything else."""
    try:
        px = np.array(pixels, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"pixels must be numeric, shape (D, 2): {exc}") from None
    if px.size == 0:
        px = px.reshape(0, 2)
    if px.ndim != 2 or px.shape[1] != 2:
        raise InvalidInput(f"pixels must have shape (D, 2), got {px.shape}")
    if not np.all(np.isfinite(px)):
        raise InvalidInput("pixels contain NaN or infinite values")
    n = px.shape[0]
    if pixel_cov is None:
        sigma = float(pixel_sigma)
        if not math.isfinite(sigma) or sigma <= 0:
            raise InvalidInput(f"pixel_sigma must be a positive number of pixels, got {sigma}")
        R = np.broadcast_to(np.eye(2) * sigma**2, (n, 2, 2)).copy()
    else:
        R = _as_covariances(pixel_cov, n, "pixel_cov")
    try:
        h = np.array(heights, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"heights must be numeric metres: {exc}") from None
    if h.ndim == 0:
        h = np.full(n, float(h))
    if h.shape != (n,) or not np.all(np.isfinite(h)) or np.any(np.abs(h) > 10.0):
        raise InvalidInput(f"heights must be {n} finite values in [-10, 10] m, one per pixel")
    kind = [k or "unknown" for k in _as_strings(kinds, n, "kinds", KINDS)]
    lab = _as_strings(labels, n, "labels")
    named = [v for v in lab if v is not None]
    if len(named) != len(set(named)):
        raise InvalidInput("a camera frame holds the same label twice")
    return px, R, h, kind, lab


def with_camera_error(
    cam: NetworkCamera, px: Array, R: Array, h: Array, sigma: float
) -> tuple[Array, Array]:
    """Return the pixel covariances R (D, 2, 2) plus the camera's calibration error
    (`sigma`, camera_error_std, on the floor, through d pixel / d(x, y) where the pixel meets its
    height's plane), and each detection's floor position standard deviation from its pixel
    covariance (larger axis, m; inf where the ray misses its plane)."""
    floor_std = np.full(px.shape[0], np.inf)
    if px.shape[0] == 0:
        return R, floor_std
    out = R.copy()
    for value in np.unique(h):
        sel = np.flatnonzero(h == value)
        try:
            est = locate_monocular(cam, px[sel], float(value), pixel_cov=R[sel])
        except InvalidInput:
            continue  # a ray that misses the plane: the association refuses it anyway
        xy = est.xy
        # A pixel whose ray misses the plane has no floor point: nothing to add there.
        ok = np.all(np.isfinite(xy), axis=1)
        worst = largest_variance(est.cov)
        floor_std[sel[ok]] = np.sqrt(np.maximum(worst[ok], 0.0))
        if sigma <= 0:
            continue
        if not ok.any():
            continue
        proj = project_plane(cam, xy[ok], float(value), jacobian=True)
        assert proj.jacobian is not None
        J = proj.jacobian
        add = sigma**2 * (J @ transposed(J))
        good = np.all(np.isfinite(add), axis=(1, 2))
        out[sel[ok][good]] += add[good]
    return out, floor_std


def inside_a_robot(
    cam: NetworkCamera,
    px: Array,
    R: Array,
    h: Array,
    kind: list[str],
    robots: Array,
    body_radius: float,
) -> NDArray[np.bool_]:
    """Return which detections are "person" ones whose floor point lies within
    `body_radius` (m) of a robot (`robots` (R, 2): where the robots' tracks are, m): a camera
    that missed the robot's marker fits its body (with a person beside it, or its mast) as a
    person, and nobody stands inside the robot. Such detections are left out like vague
    ones."""
    out = np.zeros(px.shape[0], dtype=bool)
    person = np.array([k == "person" for k in kind], dtype=bool)
    if not robots.shape[0] or not person.any():
        return out
    for value in np.unique(h[person]):
        sel = np.flatnonzero(person & (h == value))
        try:
            est = locate_monocular(cam, px[sel], float(value), pixel_cov=R[sel])
        except InvalidInput:
            continue
        d = np.linalg.norm(est.xy[:, None] - robots[None], axis=2)  # NaN: ray missed
        out[sel] = np.any(np.nan_to_num(d, nan=np.inf) < body_radius, axis=1)
    return out
