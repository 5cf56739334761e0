"""The twin's people: each walks a script, and they give way to each other as people do.

A walker's script (`Walker`) is a polyline walked at constant speed with pauses at waypoints;
`script_positions` is where the script puts it at script time s. Alone, a walker's script time
is the clock. Together, two scripts may bring two bodies into the same place at once, which no
camera could tell apart and no person would do; so a `Crowd` steps everybody on a fixed grid of
`dt` seconds and lets a walker wait (its script time stops while the clock runs) when walking on
would take it too close to someone else:

* Right of way goes by the order of the scene's `people`: walker i gives way to every walker
  j < i. Before each step it looks `horizon_s` ahead along j's script; if its next position
  comes within `comfort_m` (surface to surface) of where j will be, it waits. It does not wait
  when it already stands within that distance, since standing there would block j: it walks
  on out of the way, as a person already on a crossing does.
* Nobody steps into contact (`contact_m` surface to surface) with anyone, whatever the order:
  the walker with right of way waits too if the other stands in its way.
* A walker that has waited `max_wait_s` walks on whatever the others do, so that a script
  that makes two people meet head-on in a corridor cannot freeze the home for ever; the time
  bodies then overlap is counted (`overlap_s`), so a scenario can report it.

Script time only ever stops (never runs backwards), so every walker stays on its polyline, and
the walk is a deterministic function of time: `positions(times)` steps the grid as far as
needed and interpolates between grid instants. The crowd keeps `keep_s` seconds of history
behind the newest step it took (a twin may run for days); a query older than that starts the
walk again from time 0, which gives the same answer.

`crowd_around` puts the scene's robot, driving a given drive, into the crowd with right of way
(the walkers give way to it); `robot_poses` is where it then is.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Sequence
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.sim.scene import Scene, Walker

Array = NDArray[np.float64]

DT_S = 0.05
HORIZON_S = 2.0
COMFORT_M = 0.45
CONTACT_M = 0.05
MAX_WAIT_S = 20.0
KEEP_S = 600.0


class _Script:
    """One walker's script as key frames of one round: (script time, position)."""

    def __init__(self, walker: Walker) -> None:
        w = np.asarray(walker.waypoints, dtype=np.float64)
        n = len(w)
        pauses = np.asarray(walker.pauses if walker.pauses else [0.0] * n, dtype=np.float64)
        order = [*range(n), 0] if walker.loop else [*range(n), *range(n - 2, -1, -1)]
        # A pause is two key frames at one place.
        key_t = [0.0]
        key_p = [w[order[0]]]
        for a, b in itertools.pairwise(order):
            key_t.append(key_t[-1] + float(np.linalg.norm(w[b] - w[a])) / walker.speed)
            key_p.append(w[b])
            if pauses[b] > 0:
                key_t.append(key_t[-1] + float(pauses[b]))
                key_p.append(w[b])
        self.kt = np.asarray(key_t)
        self.kp = np.asarray(key_p)
        self.start = w[0]

    def at(self, s: Array) -> Array:
        """Positions (N, 2) at script times `s` (N,)."""
        if self.kt[-1] <= 0:
            return np.repeat(self.start[None], len(s), axis=0)
        u = np.mod(s, self.kt[-1])
        x = np.interp(u, self.kt, self.kp[:, 0])
        return np.stack([x, np.interp(u, self.kt, self.kp[:, 1])], axis=1)


class _Path:
    """A vehicle's planned motion as a script: positions `xy` (M, 2) at times `t` (M,),
    linear between, held at the ends."""

    def __init__(self, t: Array, xy: Array) -> None:
        self.kt = np.asarray(t, dtype=np.float64)
        self.kp = np.asarray(xy, dtype=np.float64)
        if self.kt.ndim != 1 or self.kp.shape != (len(self.kt), 2) or len(self.kt) < 2:
            raise InvalidInput("a vehicle's path needs times (M,) and positions (M, 2), M >= 2")

    def at(self, s: Array) -> Array:
        """Positions (N, 2) at script times `s` (N,)."""
        x = np.interp(s, self.kt, self.kp[:, 0])
        return np.stack([x, np.interp(s, self.kt, self.kp[:, 1])], axis=1)


def script_positions(walker: Walker, times: ArrayLike) -> Array:
    """Return the walker's floor positions (N, 2) metres at script times `times` (N,) s.

    It walks its waypoint polyline at constant speed from the first waypoint; with `loop` it
    returns along the closing segment and goes round again, otherwise it turns back at the ends.
    Reaching waypoint i it stands still for `pauses[i]` seconds (the first waypoint's pause
    comes at the end of each round, so the walk starts at once).
    """
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    return _Script(walker).at(t)


class Crowd:
    """The scene's walkers stepping together on a grid of `dt` seconds, giving way to each
    other (see the module's docstring for the rules). `vehicles` (times (M,), positions (M, 2),
    radius) are planned motions, a robot's drive, that come first: they have right of way over
    every walker and stop only for someone in contact ahead; members are vehicles, then
    walkers, in `positions` and `script_times`."""

    def __init__(
        self,
        walkers: Sequence[Walker],
        *,
        dt: float = DT_S,
        horizon_s: float = HORIZON_S,
        comfort_m: float = COMFORT_M,
        contact_m: float = CONTACT_M,
        max_wait_s: float = MAX_WAIT_S,
        keep_s: float = KEEP_S,
        vehicles: Sequence[tuple[ArrayLike, ArrayLike, float]] = (),
    ) -> None:
        if not dt > 0 or not horizon_s >= 0 or not keep_s > 0:
            raise InvalidInput(
                "crowd needs dt > 0, horizon_s >= 0 and keep_s > 0; "
                f"got {dt}, {horizon_s}, {keep_s}"
            )
        paths: list[_Script | _Path] = [
            _Path(np.asarray(t), np.asarray(xy)) for t, xy, _ in vehicles
        ]
        self._scripts = paths + [_Script(w) for w in walkers]
        radius = np.array([r for *_, r in vehicles] + [w.radius for w in walkers], dtype=float)
        self._comfort = radius[:, None] + radius[None, :] + comfort_m
        self._contact = radius[:, None] + radius[None, :] + contact_m
        self._touch = radius[:, None] + radius[None, :]
        speed = [
            float(np.max(np.linalg.norm(np.diff(p.kp, axis=0), axis=1) / np.diff(p.kt)))
            for p in paths
        ]
        self._speed = np.array(speed + [w.speed for w in walkers], dtype=np.float64)
        self._dt = dt
        self._ahead = dt * np.arange(1, max(1, round(horizon_s / dt)) + 1)
        self._max_wait = max(1, round(max_wait_s / dt))
        self._keep = max(2, round(keep_s / dt))
        self._lock = threading.Lock()
        self._restart()

    def __len__(self) -> int:
        return len(self._scripts)

    @property
    def overlap_s(self) -> float:
        """Seconds (summed over pairs) that two bodies overlapped in the steps taken so far."""
        return self._overlap_steps * self._dt

    def positions(self, times: ArrayLike) -> Array:
        """Return every member's position (N, B, 2) metres at `times` (N,) seconds."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise InvalidInput("crowd times must be a finite 1-D array of seconds")
        B = len(self._scripts)
        if B == 0:
            return np.zeros((len(t), 0, 2))
        if B == 1:
            return self._scripts[0].at(t)[:, None, :]
        s = self._script_times(t)
        return np.stack([sc.at(s[:, b]) for b, sc in enumerate(self._scripts)], axis=1)

    # ----------------------------------------------------------------------------------------

    def _restart(self) -> None:
        B = len(self._scripts)
        self._first = 0  # grid index of row 0 of the history
        self._hist = np.zeros((1024, B), dtype=np.int64)  # steps each walker has waited
        self._n = 1
        self._waiting = np.zeros(B, dtype=np.int64)  # consecutive steps waited
        self._overlap_steps = 0
        self._protect = 0  # oldest grid index the query being answered needs
        self._now: Array = (
            np.stack([sc.at(np.zeros(1))[0] for sc in self._scripts]) if B else np.zeros((0, 2))
        )

    def script_times(self, times: ArrayLike) -> Array:
        """Return every member's script time (N, B) at clock times `times` (N,): the clock
        minus the time it has waited (a vehicle's pose at t is its path's at that time)."""
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise InvalidInput("crowd times must be a finite 1-D array of seconds")
        if len(self._scripts) == 0:
            return np.zeros((len(t), 0))
        return self._script_times(t)

    def _script_times(self, t: Array) -> Array:
        """Script times (N, B) at clock times t: the clock minus the time waited, linear between
        grid instants. Times before 0 are script times (nobody has waited yet)."""
        dt = self._dt
        g = np.floor(np.maximum(t, 0.0) / dt).astype(np.int64)
        with self._lock:
            if len(g) and g.min() < self._first:
                self._restart()
            if len(g):
                self._protect = int(g.min())
                self._step_to(int(g.max()) + 1)
            w0 = self._hist[g - self._first]
            w1 = self._hist[g + 1 - self._first]
        frac = (np.maximum(t, 0.0) - g * dt)[:, None]
        s0 = (g[:, None] - w0) * dt
        s1 = (g[:, None] + 1 - w1) * dt
        s = s0 + (s1 - s0) * (frac / dt)
        return np.where(t[:, None] < 0, t[:, None], s)

    def _step_to(self, last: int) -> None:
        """Take grid steps until the history holds grid index `last`."""
        while self._first + self._n - 1 < last:
            self._step()

    def _step(self) -> None:
        dt = self._dt
        k = self._first + self._n - 1  # grid index of the newest row
        waited = self._hist[self._n - 1].copy()
        s = (k - waited) * dt
        now = self._now
        nxt = now.copy()
        for i, script in enumerate(self._scripts):
            # Options in order of preference: on along the script, stand, one step back.
            options = (script.at(s[i : i + 1] + dt)[0], now[i], script.at(s[i : i + 1] - dt)[0])
            clear = self._clearance(i, options, s, now)
            if clear[0] >= 0 or clear[1] < 0 <= clear[0] - clear[1]:
                pick = 0  # clear ahead, or in someone's way and walking on gets out of it
            elif clear[1] >= 0:
                pick = 1  # wait at the edge of the other's way
            else:
                pick = int(np.argmax(clear))
            others = np.delete(np.where(np.arange(len(now))[:, None] < i, nxt, now), i, axis=0)
            if pick != 1 and self._touches(i, options[pick], now[i], others):
                pick = 1
            if pick != 0 and self._waiting[i] >= self._max_wait:
                pick = 0  # a script that makes two people meet head-on: walk on regardless
            self._waiting[i] = 0 if pick == 0 else self._waiting[i] + 1
            waited[i] += pick
            nxt[i] = options[pick]
        d = np.linalg.norm(nxt[:, None, :] - nxt[None, :, :], axis=2)
        self._overlap_steps += int(np.count_nonzero(np.triu(d < self._touch, 1)))
        self._now = nxt
        self._append(waited)

    def _clearance(self, i: int, options: tuple[Array, ...], s: Array, now: Array) -> Array:
        """For each candidate position of walker i: the smallest gap (m), over the walkers
        before it, between the candidate and where they will be in the next `horizon_s`,
        minus the comfort distance (negative: in their way); +inf when nobody is near."""
        cand = np.stack(options)
        out = np.full(len(options), np.inf)
        for j in range(i):
            reach = self._comfort[i, j] + self._ahead[-1] * (self._speed[i] + self._speed[j])
            if np.linalg.norm(now[i] - now[j]) > reach + 0.1:
                continue
            path = np.vstack([now[j], self._scripts[j].at(s[j] + self._ahead)])
            gap = np.linalg.norm(cand[:, None, :] - path[None, :, :], axis=2).min(axis=1)
            out = np.minimum(out, gap - self._comfort[i, j])
        return out

    def _touches(self, i: int, cand: Array, here: Array, others: Array) -> bool:
        """Whether moving walker i from `here` to `cand` comes into contact with anyone in
        `others` (the other walkers' positions, in order, without i), closing the distance."""
        contact = np.delete(self._contact[i], i)
        d_new = np.linalg.norm(others - cand, axis=1)
        d_old = np.linalg.norm(others - here, axis=1)
        return bool(np.any((d_new < contact) & (d_new < d_old)))

    def _append(self, row: NDArray[np.int64]) -> None:
        if self._n == len(self._hist):
            drop = min(self._n - self._keep, self._protect - self._first)
            if self._n >= 2 * self._keep and drop > 0:
                self._hist[: self._n - drop] = self._hist[drop : self._n]
                self._first += drop
                self._n -= drop
            else:
                grown = np.zeros((2 * len(self._hist), self._hist.shape[1]), dtype=np.int64)
                grown[: self._n] = self._hist[: self._n]
                self._hist = grown
        self._hist[self._n] = row
        self._n += 1


@lru_cache(maxsize=8)
def _crowd(people_json: tuple[str, ...]) -> Crowd:
    return Crowd([Walker.model_validate_json(p) for p in people_json])


def crowd_of(people: Sequence[Walker]) -> Crowd:
    """Return the (shared, cached) crowd of these walkers: scenarios, the renderer's callers and
    the scoring all ask it for the same walk."""
    return _crowd(tuple(w.model_dump_json() for w in people))


def walkers_at(scene: Scene, times: Array) -> Array:
    """Return the scene's walkers' floor positions (N, B, 2) at `times` (N,) s, as their shared
    crowd walks them (no robot among them)."""
    return crowd_of(scene.people).positions(times)


def crowd_around(scene: Scene, drive: Array) -> Crowd:
    """Return the scene's walkers and its robot, which drives `drive` (poses (N, 3) every
    0.05 s from time 0), as one crowd: the robot first (right of way; it stops only for
    someone in its way), then the walkers, giving way to it and to each other."""
    if scene.robot is None:
        return crowd_of(scene.people)
    tt = np.arange(len(drive)) * 0.05
    return Crowd(scene.people, vehicles=[(tt, drive[:, :2], scene.robot.base_radius)])


def robot_poses(crowd: Crowd, drive: Array, times: Array) -> Array:
    """Return the robot's poses (N, 3) at `times` in a crowd_around crowd: its drive's poses
    at its script times (the drive held while it waits for somebody)."""
    s = crowd.script_times(times)[:, 0]
    tt = np.arange(len(drive)) * 0.05
    yaw = np.unwrap(drive[:, 2])
    return np.column_stack([np.interp(s, tt, c) for c in (drive[:, 0], drive[:, 1], yaw)])
