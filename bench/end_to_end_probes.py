"""What the end-to-end bench measures from outside the service, by its public API only: the
twin's truth polled on GET /twin (each step's capture interval and the robot's true position),
the robot's stored track points, and the arrival of /ws/targets messages (latency)."""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from websockets.sync.client import connect

from bench.end_to_end_service import HEADERS, TwinService

# (s): the stamp is taken in the same locked block as the pose, so only the two processes'
# scheduling separates them; steps are 200 ms apart, so the match is never ambiguous.
_MATCH_SLACK_S = 0.03


@dataclass
class TruthPoller:
    """Polls GET /twin; keeps (sent, received, sim_time, x, y) of every answer."""

    service: TwinService
    rows: list[tuple[float, float, float, float, float]] = field(default_factory=list)

    def poll(self) -> float:
        """Ask once; return the twin's simulated time (NaN before its robot moves)."""
        sent = time.time()
        state = self.service.get("/twin")
        received = time.time()
        robot = state.get("robot")
        if robot is None:
            return float("nan")
        self.rows.append((sent, received, state["sim_time"], robot["x"], robot["y"]))
        return float(state["sim_time"])

    def steps(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Return each step seen: its simulated time (K,), the interval [lo, hi] (K, 2) its
        capture time lies in (Unix s), and the robot's true position (K, 2)."""
        rows = np.array(self.rows, dtype=np.float64).reshape(-1, 5)
        sim = rows[:, 2]
        first = np.flatnonzero(np.r_[True, np.diff(sim) > 0])
        # A step is stamped after the previous step's last answer was sent and before its own
        # first answer came back.
        lo = np.r_[-np.inf, rows[first[1:] - 1, 0]]
        hi = rows[first, 1]
        return sim[first], np.column_stack([lo, hi]), rows[first][:, 3:5]

    def truth_at(self, t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Return the simulated time (N,) and true robot position (N, 2) of each capture time
        `t` (N,), NaN where no seen step's interval holds it."""
        sim, window, xy = self.steps()
        lo = window[:, 0] - _MATCH_SLACK_S
        hi = window[:, 1] + _MATCH_SLACK_S
        inside = (t[:, None] >= lo[None, :]) & (t[:, None] <= hi[None, :])
        one = inside.sum(axis=1) == 1
        k = np.argmax(inside, axis=1)
        out_sim = np.where(one, sim[k], np.nan)
        out_xy = np.where(one[:, None], xy[k], np.nan)
        return out_sim, out_xy


class PositionsListener:
    """A /ws/targets client in a thread: the arrival time (this machine's clock) and the robot
    target's observation time (its own `t`, the newest when several) of every positions
    message that holds a robot target."""

    def __init__(self, service: TwinService) -> None:
        url = service.api.replace("http://", "ws://") + "/ws/targets"
        self._ws = connect(url, additional_headers=HEADERS, open_timeout=10)
        self.messages: list[tuple[float, float]] = []
        self._thread = threading.Thread(target=self._run, name="ws", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            for raw in self._ws:
                arrived = time.time()
                message = json.loads(raw)
                robots = [
                    float(t["t"])
                    for t in message.get("targets", [])
                    if t["kind"] == "robot" and t.get("t") is not None
                ]
                if robots:
                    self.messages.append((arrived, max(robots)))
        except Exception:  # the socket closes when the listener or the service stops
            return

    def latency(self, stamps: NDArray[np.float64]) -> NDArray[np.float64]:
        """Return, per capture time in `stamps` (N,), the delay until the first message that
        holds the robot updated by an observation at least that recent (NaN when none
        came)."""
        got = np.array(self.messages, dtype=np.float64).reshape(-1, 2)
        if got.shape[0] == 0:
            return np.full(stamps.shape, np.nan)
        # The robot's observation time only grows, except when its target ends; a running
        # maximum makes "the first message at least as recent" a sorted search.
        newest = np.maximum.accumulate(got[:, 1])
        i = np.searchsorted(newest, stamps, side="left")
        ok = i < got.shape[0]
        out = np.full(stamps.shape, np.nan)
        out[ok] = got[i[ok], 0] - stamps[ok]
        return out

    def close(self) -> None:
        self._ws.close()
        self._thread.join(5)


def robot_points(service: TwinService) -> NDArray[np.float64]:
    """Return every stored track point (t, x, y) of the robot's targets, in time order."""
    rows: list[list[float]] = []
    for target in service.get("/targets", kind="robot", state="all", limit=100)["items"]:
        track = service.get(f"/targets/{target['id']}/track", limit=10_000)["points"]
        rows += [[p["t"], p["xy"][0], p["xy"][1]] for p in track]
    points = np.array(rows, dtype=np.float64).reshape(-1, 3)
    return points[np.argsort(points[:, 0])]
