"""A stand-in for the live 3D scene that records every call the service makes to it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class SceneRecorder:
    """Records every call by method name (`calls[name]`: the arguments of each call); each call
    returns `answer` (what the scene says back, such as whether an image was shown)."""

    def __init__(self, answer: Any = None) -> None:
        self.calls: dict[str, list[tuple]] = {}
        self._answer = answer

    def __getattr__(self, name: str) -> Callable[..., Any]:
        def record(*args: Any) -> Any:
            self.calls.setdefault(name, []).append(args)
            return self._answer

        return record
