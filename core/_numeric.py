"""Small numeric kernels shared by the estimators."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

# OpenBLAS runs dot products of more than about 10,000 elements on several threads, which on
# busy cores costs milliseconds where the arithmetic takes microseconds; past this size the sum
# is taken without BLAS.
_BLAS_DOT_MAX = 8192


def dot(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Return sum(a * b) of two equal-shaped contiguous arrays, on one thread."""
    if a.size <= _BLAS_DOT_MAX:
        return float(np.vdot(a, b))
    return float(np.einsum("i,i->", a.ravel(), b.ravel()))
