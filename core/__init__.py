"""intspace core: the measurement science (numpy + OpenCV, no I/O, no database, no web)."""

from core.errors import (
    ConvergenceError,
    DegenerateConfiguration,
    IntspaceError,
    InvalidInput,
    NotEnoughPoints,
    PatternNotFound,
)

__all__ = [
    "ConvergenceError",
    "DegenerateConfiguration",
    "IntspaceError",
    "InvalidInput",
    "NotEnoughPoints",
    "PatternNotFound",
]
