"""Taking over the tracks another tracker followed (Tracker.restore): the checks of their
snapshots and their states and covariances predicted from each snapshot's own time to the
restore time."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.localization._checks import check_time
from core.localization._projection import transposed
from core.localization.tracks import KINDS, LIVE_STATES, TrackSnapshot

Array = NDArray[np.float64]


def restored_states(
    snaps: Sequence[TrackSnapshot], t: float, q: float, known: Sequence[int]
) -> tuple[Array, Array]:
    """Return the states (n, 4) and symmetrised covariances (n, 4, 4) of the snapshots
    predicted to time t (s) by the constant-velocity model of acceleration density q; raise
    InvalidInput unless each is a confirmed or coasting track of a known kind, no later than
    t, with an id >= 1 new to the tracker (`known`: its ids) and a finite state with a
    symmetric positive semi-definite covariance."""
    n = len(snaps)
    ids = [s.id for s in snaps]
    for s in snaps:
        if not isinstance(s, TrackSnapshot):
            raise InvalidInput(f"restore takes TrackSnapshot objects, got {type(s).__name__}")
        if isinstance(s.id, bool) or not isinstance(s.id, int | np.integer) or s.id < 1:
            raise InvalidInput(f"a track id must be an integer >= 1, got {s.id!r}")
        if s.state not in LIVE_STATES:
            raise InvalidInput(
                f"track {s.id} is {s.state}: only confirmed or coasting tracks are restored"
            )
        if s.kind not in KINDS:
            raise InvalidInput(f"track {s.id} has kind {s.kind!r}, not one of {KINDS}")
        when = check_time(s.t)
        if when > t:
            raise InvalidInput(f"track {s.id} is at t = {when} s, after the restore time {t} s")
        if not s.first_seen <= s.last_seen <= t:
            raise InvalidInput(
                f"track {s.id} needs first_seen <= last_seen <= {t} s, got "
                f"{s.first_seen} and {s.last_seen}"
            )
    if len(set(ids)) != n or set(ids) & set(known):
        raise InvalidInput("restored track ids must be distinct and new to this tracker")
    if n == 0:
        return np.zeros((0, 4)), np.zeros((0, 4, 4))
    x = np.array([np.asarray(s.x, dtype=np.float64) for s in snaps])
    P = np.array([np.asarray(s.cov, dtype=np.float64) for s in snaps])
    if x.shape != (n, 4) or P.shape != (n, 4, 4):
        raise InvalidInput(f"each snapshot needs x (4,) and cov (4, 4), got {x.shape[1:]}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
        raise InvalidInput("restored states and covariances must be finite")
    if np.any(np.abs(P - transposed(P)) > 1e-9 * (1.0 + np.abs(P))):
        raise InvalidInput("restored covariances must be symmetric")
    if np.any(np.linalg.eigvalsh(P)[:, 0] < -1e-12):
        raise InvalidInput("restored covariances must be positive semi-definite")
    # Each snapshot predicted from its own time to t: the batch form of cv_transition and
    # cv_process_noise.
    dt = t - np.array([float(s.t) for s in snaps])
    F = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    F[:, 0, 2] = F[:, 1, 3] = dt
    Q = np.zeros((n, 4, 4))
    Q[:, 0, 0] = Q[:, 1, 1] = q * dt**3 / 3.0
    Q[:, 0, 2] = Q[:, 2, 0] = Q[:, 1, 3] = Q[:, 3, 1] = q * dt**2 / 2.0
    Q[:, 2, 2] = Q[:, 3, 3] = q * dt
    x = np.einsum("nij,nj->ni", F, x)
    P = F @ P @ transposed(F) + Q
    return x, 0.5 * (P + transposed(P))
