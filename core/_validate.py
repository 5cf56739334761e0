"""Shape and value checks shared by every public function (done once, at the boundary)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput, NotEnoughPoints


def as_numeric(x: ArrayLike, name: str, shapes: str) -> NDArray[np.float64]:
    """Return a float64 copy of `x`; raise InvalidInput naming the expected `shapes` (as the
    caller words them, e.g. "(B, 2) or (2,)") when it is not numeric. Shape and finiteness are
    the caller's to check."""
    try:
        return np.array(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be numeric, shape {shapes}: {exc}") from None


def as_points(x: ArrayLike, dim: int, name: str, min_count: int = 0) -> NDArray[np.float64]:
    """Return `x` as a finite float64 array of shape (N, dim); raise InvalidInput otherwise."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be numeric, shape (N, {dim}): {exc}") from None
    if a.ndim != 2 or a.shape[1] != dim:
        raise InvalidInput(f"{name} must have shape (N, {dim}), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInput(f"{name} contains NaN or infinite values; remove or fix those points")
    if a.shape[0] < min_count:
        raise NotEnoughPoints(f"{name} has {a.shape[0]} points; at least {min_count} are needed")
    return a


def as_matrix(x: ArrayLike, shape: tuple[int, ...], name: str) -> NDArray[np.float64]:
    """Return `x` as a finite float64 array of exactly `shape`; raise InvalidInput otherwise."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be a numeric array of shape {shape}: {exc}") from None
    if a.shape != shape:
        raise InvalidInput(f"{name} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInput(f"{name} contains NaN or infinite values")
    return a
