"""Typed errors raised at the boundary of every estimator.

Each message says what was wrong with the input and what to do about it, so that the service can
hand it to a user unchanged (as a 4xx) and a script can catch the precise kind.
"""


class IntspaceError(Exception):
    """Base class of every error the measurement core raises on purpose."""


class InvalidInput(IntspaceError, ValueError):
    """Arrays of the wrong shape or type, non-finite values (NaN, inf), or an unknown option."""


class NotEnoughPoints(InvalidInput):
    """Fewer observations than the estimator's minimum (e.g. fewer than 4 correspondences)."""


class DegenerateConfiguration(IntspaceError, ValueError):
    """The data do not determine the estimate: collinear points, a plane seen edge-on or
    fronto-parallel where that removes constraints, a rank-deficient system."""


class ConvergenceError(IntspaceError, RuntimeError):
    """An iterative estimator failed to reach a usable solution (diverged or produced NaN)."""


class PatternNotFound(IntspaceError):
    """A calibration pattern was not found in enough images to calibrate."""
