"""Typed errors of the manipulation core, refined from core.errors so that a caller catching the
general kind (DegenerateConfiguration, NotEnoughPoints, InvalidInput) catches these too."""

from __future__ import annotations

from core.errors import DegenerateConfiguration, InvalidInput, NotEnoughPoints


class TooFewMotions(NotEnoughPoints):
    """Hand-eye calibration was given fewer poses than it needs (three poses: two motions)."""


class DegenerateMotions(DegenerateConfiguration):
    """The arm's motions do not determine the hand-eye transform: every rotation axis is
    parallel (or every rotation too small), so the rotation about that axis and the
    translation along it are unobservable."""


class Unreachable(InvalidInput):
    """A target pose the arm (or the whole mobile manipulator) cannot reach within its limits."""
