"""What the service's background jobs share: the names their workers hold claims under, and
how a conditional UPDATE (a claim) says whether it took."""

from __future__ import annotations

import os
import socket
import uuid
from typing import Any, cast

from sqlalchemy.engine import CursorResult, Result


def worker_id() -> str:
    """Return a name for this executor that no other process shares: host, pid and a nonce
    (a pid is reused after a restart, the nonce is not)."""
    return f"{socket.gethostname()[:80]}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


def rows_changed(result: Result[Any]) -> int:
    """Return how many rows the UPDATE whose result this is changed (a claim, a renewal or a
    write conditional on holding one is taken when it changed exactly the row it meant)."""
    return int(cast(CursorResult[Any], result).rowcount or 0)
