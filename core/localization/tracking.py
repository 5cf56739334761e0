"""Multi-target tracking on the floor from unsynchronised cameras: one asynchronous EKF.

Each track is a body moving on the floor with the state s = (x, y, vx, vy) (m, m/s) and its
covariance P (4 x 4). Between two updates, whatever their spacing, the state follows the
continuous white noise acceleration model (Bar-Shalom, Li & Kirubarajan, "Estimation with
Applications to Tracking and Navigation", 2001, sec. 6.2.2): per axis

    F(dt) = [[1, dt], [0, 1]],    Q(dt) = q [[dt^3 / 3, dt^2 / 2], [dt^2 / 2, dt]],

with q the power spectral density of the acceleration (m^2 / s^3). Q is the integral of the
continuous noise over the elapsed time, so frames that arrive milliseconds apart add
milliseconds' worth of uncertainty and a camera that reports after a second adds a second's: the
filter is the same whether the cameras are synchronised or not.

A detection is a pixel u (2,) with its covariance R (2 x 2) of a point of the body at a known
height h above the floor (the robot's marker, a person's axis point), seen by one camera k at
time t. The measurement function is that camera's projection of (x, y, h), with lens distortion
(core.localization._projection.project_plane), so the update is the extended Kalman filter's
(ibid. sec. 10.3.2) with H = [J 0], J = d pi_k(x, y, h) / d(x, y) at the prediction, in Joseph
form. One camera's detection moves a track along the directions that camera resolves; the
next camera's, milliseconds later, along its own: a body seen by one camera is tracked, one
seen by several is fused, and no detections are grouped across cameras.

Where two confirmed tracks could both explain a detection almost equally well (their costs
within `ambiguity`), the detection keeps the track alive but does not move it, for at most
`ambiguity_coast` seconds: crossing bodies coast through the crossing on their own velocities
instead of being pulled onto each other's paths, which is what swaps identities.

A detection whose floor position is uncertain by more than `located_std` (a blob of two
people one behind the other, placed by its width alone; a head seen past a door jamb) is left
out: such blobs are also off in bearing, and one of them pulls a track onto the wrong body more
surely than a short coast loses it.

Association, frame by frame (one camera, one time): the cost of detection j for track i is
d2 + ln det S, with d2 = nu^T S^-1 nu the squared Mahalanobis distance of the pixel innovation
nu = u_j - pi_k(x_i) (S = J P J^T + R): the negative log-likelihood up to a constant, so a vague
track does not win a detection from a precise one merely by its wide gate. Pairs above the
chi-square gate or of incompatible kinds (a "robot" detection never updates a "person" track;
"unknown" matches both), and unlabelled pairs whose track the camera cannot see past the
occluders (walls, tall furniture: a vague track in the next room does not take a detection
through the wall), are forbidden, and scipy.optimize.linear_sum_assignment solves the
rest in rounds: detections with a label go to the track of that label; then confirmed and
coasting tracks take their detections; then tentative tracks take what is left, so a track born
from clutter beside a target cannot take that target's detection.

Appearance: a detection may come with a descriptor of its look (core.localization.appearance:
colour histograms of a person's box). Each track keeps, per camera, the running mean of the
descriptors of the detections that updated it unambiguously (each new one weighs
`appearance_rate`), and a pairing's assignment cost adds `appearance_weight` times the
Bhattacharyya distance between the detection's descriptor and the track's in that camera (only
in the same camera: colour responses differ between cameras). The term only breaks ties between
the pairings the gate allows: at the default 4 units, a detection whose colours share nothing
with a track's (distance 1) must be e^2 (about 7) times likelier by position to be taken over
one that matches, so two people side by side keep their identities while a person whose look
changes (into shade, turning round) is still followed by position. It enters the costs that
`ambiguity` compares, so two crossing bodies of different looks need not coast, and it never
enters a tentative track's score, which stays the position's likelihood ratio.

A body is also recognised by its look after it was lost (behind a pillar, a passer-by, out of
the detector's reach for a few seconds). A coasting track with a look that grows vaguer than
`max_position_std` does not end there: it is lost, takes no detection and blocks no birth, and
waits up to `end_after` seconds. When a new track is confirmed, a lost track whose look in a
camera both were seen by lies within `recognition_distance` of the new one's, and which could
have walked to the new track's position since its last update (at WALKING_SPEED, plus three
standard deviations of the new position), goes on as that body: it takes the new track's state,
and the new track is dropped. A track without a look ends as before.

Life cycle, by elapsed time (never by frame count, since cameras report at their own rates):

* a detection no track takes starts a TENTATIVE track at its back-projection onto Z = h (speed
  unknown: N(0, `initial_speed_std`^2) per axis), unless it lies within `min_separation` metres
  of a live track or within `birth_gate` of it: two bodies do not stand inside each other, so it
  is that target's outlier (a second blob of one person, the robot's body seen as a person);
  tracks the camera cannot see past the occluders do not count (no blob is the outlier of a
  body behind a wall);
* a tentative track carries the log-likelihood ratio of "a body" against "clutter" of what the
  cameras reported (the sequential track score of Blackman & Popoli, "Design and Analysis of
  Modern Tracking Systems", 1999, sec. 6.2): each update adds ln(p_D N(nu; 0, S) / lambda),
  lambda the clutter density per pixel, and each frame of a camera that has the track in view
  but gave it no detection adds ln(1 - p_D) (in view: not hidden by the occluders, nor behind
  another track's body, nor inside the gate of a detection left out as too vague). A track
  born from clutter collects small or negative terms (its detections fall anywhere in a wide
  gate) and is soon dropped; a body's collect large ones. It becomes CONFIRMED when its
  score reaches `confirm_score` with at least `confirm_hits` updates within `confirm_window`
  seconds of its birth, and is dropped when the score falls below `drop_score`, the window
  passes, or it goes `tentative_timeout` seconds without an update. Both times stretch for a
  camera that reports slowly (a node on a slow machine, detecting every third frame): the
  window to `CONFIRM_GAPS` of the spacing of the frames of the camera that last saw the track
  (a running mean of that camera's frame intervals up to `MAX_FRAME_GAP`; a longer pause is a
  silence, not a rate), the timeout to `TENTATIVE_GAPS` of them,
  so a body seen by a camera reporting twice a second is confirmed like one seen ten times a
  second, from its sightings' score (each weighs less: the prediction between them is vaguer);
* a confirmed track becomes COASTING after `coast_after` seconds without an update (predicted
  only; an update makes it confirmed again), and ENDED after `end_after` seconds without one,
  or earlier when its position standard deviation exceeds `max_position_std` (it could be
  anywhere; a track with a look is lost instead, to be recognised: "Appearance" above); a
  labelled track, whose body its label names, waits `labelled_end_after` seconds. Ended
  tracks leave the tracker and are reported once.

Time is Unix seconds (or any one clock): frames must come in time order; core.localization.reorder
puts frames of several cameras that arrive out of order back in order within a latency window.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.localization._checks import check_time
from core.localization._projection import inv2, project_plane, transposed
from core.localization.association import (
    ambiguous_pairs,
    assign_pairs,
    largest_variance,
    mahalanobis,
)
from core.localization.cameras import NetworkCamera
from core.localization.ground import locate_monocular
from core.localization.looks import TrackLooks
from core.localization.motion import cv_process_noise, cv_transition
from core.localization.occluders import Occluders, line_of_sight
from core.localization.tracker_config import (
    CHI2_2DOF_99,
    CHI2_2DOF_999,
    CHI2_2DOF_999999,
    CONFIRM_GAPS,
    MAX_FRAME_GAP,
    TENTATIVE_GAPS,
    WALKING_SPEED,
    TrackerConfig,
)
from core.localization.tracks import KINDS, LIVE_STATES, FrameResult, TrackSnapshot, TrackState

Array = NDArray[np.float64]

__all__ = [
    "CHI2_2DOF_99",
    "CHI2_2DOF_999",
    "CHI2_2DOF_999999",
    "CONFIRM_GAPS",
    "KINDS",
    "LIVE_STATES",
    "MAX_FRAME_GAP",
    "TENTATIVE_GAPS",
    "WALKING_SPEED",
    "FrameResult",
    "TrackSnapshot",
    "TrackState",
    "Tracker",
    "TrackerConfig",
    "cv_process_noise",
    "cv_transition",
]


def _as_covariances(cov: ArrayLike, n: int, name: str) -> Array:
    try:
        c = np.array(cov, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{name} must be numeric, shape ({n}, 2, 2): {exc}") from None
    if c.shape == (2, 2):
        c = np.broadcast_to(c, (n, 2, 2)).copy()
    if c.shape != (n, 2, 2):
        raise InvalidInput(f"{name} must have shape ({n}, 2, 2) or (2, 2), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise InvalidInput(f"{name} contains NaN or infinite values")
    det = c[:, 0, 0] * c[:, 1, 1] - c[:, 0, 1] * c[:, 1, 0]
    asym = np.abs(c[:, 0, 1] - c[:, 1, 0]) > 1e-9 * np.sqrt(np.abs(c[:, 0, 0] * c[:, 1, 1]))
    if np.any(c[:, 0, 0] <= 0) or np.any(det <= 0) or np.any(asym):
        raise InvalidInput(f"every {name} matrix must be symmetric positive definite")
    return c


def _as_strings(
    values: Sequence[str | None] | str | None, n: int, name: str, allowed: tuple[str, ...] = ()
) -> list[str | None]:
    if values is None:
        return [None] * n
    if isinstance(values, str):
        values = [values] * n
    if len(values) != n:
        raise InvalidInput(f"{name} must hold {n} values, one per detection, got {len(values)}")
    out: list[str | None] = []
    for v in values:
        if v is not None and not isinstance(v, str):
            raise InvalidInput(f"{name} must be strings or None, got {type(v).__name__}")
        if allowed and v is not None and v not in allowed:
            raise InvalidInput(f"{name} must be one of {', '.join(allowed)}, got {v!r}")
        out.append(v)
    return out


def _as_looks(appearances: ArrayLike | None, n: int) -> Array | None:
    """Return the detections' appearance descriptors as (n, F) finite non-negative floats,
    or None when none were given."""
    if appearances is None:
        return None
    try:
        look = np.array(appearances, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"appearances must be numeric, shape (D, F): {exc}") from None
    if look.size == 0 and n == 0:
        return None
    if look.ndim != 2 or look.shape[0] != n:
        raise InvalidInput(f"appearances must have shape ({n}, F), one row per pixel")
    if not np.all(np.isfinite(look)) or np.any(look < 0):
        raise InvalidInput("appearances are histograms: finite and non-negative")
    return look


class Tracker:
    """Tracks bodies on the floor from the detections of unsynchronised cameras (see module).

    cameras: the calibrated cameras, a mapping from any key (a registry id, a name) to a
    `NetworkCamera`, or a sequence (keys 0, 1, ...). config: a `TrackerConfig`. occluders: the
    walls and furniture of the floor plan (core.localization.occluders), when known: a camera
    whose view of a tentative track is hidden by them is not expected to detect it. Frames go to
    `update` in time order; `advance` moves the clock without a frame (ending silent tracks).
    Track ids are positive integers, never reused (`next_id` sets the first one, so a restarted
    tracker can go on from stored ids).
    """

    def __init__(
        self,
        cameras: Mapping[Hashable, NetworkCamera] | Sequence[NetworkCamera] | None = None,
        config: TrackerConfig | None = None,
        *,
        next_id: int = 1,
        occluders: Occluders | None = None,
    ) -> None:
        self.config = TrackerConfig() if config is None else config
        if not isinstance(self.config, TrackerConfig):
            raise InvalidInput(f"config must be a TrackerConfig, got {type(config).__name__}")
        self.cameras: dict[Hashable, NetworkCamera] = {}
        if cameras is not None:
            items = cameras.items() if isinstance(cameras, Mapping) else enumerate(cameras)
            for key, cam in items:
                self.set_camera(key, cam)
        if not isinstance(next_id, int) or next_id < 1:
            raise InvalidInput(f"next_id must be an integer >= 1, got {next_id!r}")
        self._next_id = next_id
        if occluders is not None and not isinstance(occluders, Occluders):
            raise InvalidInput(f"occluders must be Occluders, got {type(occluders).__name__}")
        self.occluders = occluders
        self._t: float | None = None
        self._x = np.zeros((0, 4))
        self._P = np.zeros((0, 4, 4))
        self._ids: list[int] = []
        self._kinds: list[str] = []
        self._labels: list[str | None] = []
        self._states: list[TrackState] = []
        self._hits: list[int] = []
        self._first: list[float] = []
        self._last: list[float] = []
        self._score: list[float] = []
        self._height: list[float] = []
        self._moved: list[float] = []  # time of the last update that moved the state
        # Each camera's last frame time and the running mean of its frame intervals (s); each
        # track's interval of the camera that last updated it (module docstring, life cycle).
        self._camera_last: dict[Hashable, float] = {}
        self._camera_gap: dict[Hashable, float] = {}
        self._gap: list[float] = []
        # Each track's look (module docstring, "Appearance"), and the lost tracks recognised
        # in the current frame (`_take_over`).
        self._looks = TrackLooks(self.config.appearance_rate)
        self._recognised_ids: list[int] = []

    # -- cameras and state ---------------------------------------------------------------------

    def set_camera(self, key: Hashable, camera: NetworkCamera) -> None:
        """Add or replace the calibration of camera `key` (e.g. after a calibration run)."""
        if not isinstance(camera, NetworkCamera):
            raise InvalidInput(f"camera {key!r} must be a NetworkCamera, got {type(camera)}")
        self.cameras[key] = camera

    @property
    def time(self) -> float | None:
        """Time of the last frame or `advance` (s), None before the first."""
        return self._t

    @property
    def next_id(self) -> int:
        """The id the next track will get."""
        return self._next_id

    def __len__(self) -> int:
        return len(self._ids)

    def tracks(
        self, t: float | None = None, *, states: Sequence[TrackState] | None = None
    ) -> tuple[TrackSnapshot, ...]:
        """Return snapshots of the tracks in `states` (all when None), predicted to time t (s)
        if given (the tracker itself is not moved)."""
        x, P, when = self._x, self._P, self._t
        if t is not None:
            t = check_time(t)
            x, P = self._predicted(t)
            when = t
        keep = None if states is None else set(states)
        return tuple(
            self._snapshot(i, x, P, when)
            for i in range(len(self._ids))
            if keep is None or self._states[i] in keep
        )

    def _snapshot(self, i: int, x: Array, P: Array, when: float | None) -> TrackSnapshot:
        return TrackSnapshot(
            id=self._ids[i],
            kind=self._kinds[i],
            label=self._labels[i],
            state=self._states[i],
            t=float("nan") if when is None else when,
            x=x[i].copy(),
            cov=P[i].copy(),
            hits=self._hits[i],
            first_seen=self._first[i],
            last_seen=self._last[i],
        )

    def _predicted(self, t: float) -> tuple[Array, Array]:
        """Return every track's state (T, 4) and covariance (T, 4, 4) predicted to time t."""
        if self._t is None:
            return self._x, self._P
        dt = t - self._t
        if dt < 0:
            raise InvalidInput(
                f"time went backwards: t = {t} s is before the tracker's time {self._t} s; "
                "feed frames in time order (ReorderBuffer sorts frames that arrive late)"
            )
        if dt == 0 or not self._ids:
            return self._x, self._P
        F = cv_transition(dt)
        x = self._x @ F.T
        P = F @ self._P @ F.T + cv_process_noise(dt, self.config.q)
        return x, P

    def advance(self, t: float) -> tuple[TrackSnapshot, ...]:
        """Move every track to time t (s) without a measurement; return the tracks that ended."""
        t = check_time(t)
        self._x, self._P = self._predicted(t)
        self._t = t
        ended, _ = self._manage()
        return ended

    def shift(self, dt: float) -> None:
        """Move the tracker's clock and every track's times on by dt seconds without any
        motion or added uncertainty: a pause of the cameras' world (the twin held still), so
        that its tracks neither coast nor end over it."""
        dt = check_time(dt)
        if dt < 0:
            raise InvalidInput(f"a shift must not go back in time, got {dt} s")
        if self._t is not None:
            self._t += dt
        self._first = [v + dt for v in self._first]
        self._last = [v + dt for v in self._last]
        self._moved = [v + dt for v in self._moved]
        self._camera_last = {k: v + dt for k, v in self._camera_last.items()}

    def restore(self, t: float, tracks: Sequence[TrackSnapshot]) -> tuple[TrackSnapshot, ...]:
        """Take over confirmed or coasting tracks another tracker followed, keeping their ids,
        and move the clock to t (s); return the tracks that ended at t (life cycle, module).

        Each snapshot's state x (4,) and cov (4, 4) hold at its own time `snap.t` <= t; it is
        predicted to t by the constant-velocity model (F(dt) x, F P F^T + Q(dt)), so snapshots
        taken at different times (stored one by one) restart in step. A snapshot whose speed is
        unknown should carry a zero velocity with `initial_speed_std`^2 variances. The ids must
        be new to this tracker; later tracks get ids after the largest. The tracks' hits, first
        and last update times, kind and label are kept; the ambiguity timer restarts at their
        last update. Tracks already here are predicted to t too.
        """
        t = check_time(t)
        if self._t is not None and t < self._t:
            raise InvalidInput(
                f"cannot restore at t = {t} s, before the tracker's time {self._t} s"
            )
        snaps = list(tracks)
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
        if len(set(ids)) != n or set(ids) & set(self._ids):
            raise InvalidInput("restored track ids must be distinct and new to this tracker")
        if n == 0:
            self._x, self._P = self._predicted(t)
            self._t = t
            return self._manage()[0]
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
        q = self.config.q
        Q = np.zeros((n, 4, 4))
        Q[:, 0, 0] = Q[:, 1, 1] = q * dt**3 / 3.0
        Q[:, 0, 2] = Q[:, 2, 0] = Q[:, 1, 3] = Q[:, 3, 1] = q * dt**2 / 2.0
        Q[:, 2, 2] = Q[:, 3, 3] = q * dt
        x = np.einsum("nij,nj->ni", F, x)
        P = F @ P @ transposed(F) + Q
        self._x, self._P = self._predicted(t)
        self._t = t
        self._x = np.concatenate([self._x, x])
        self._P = np.concatenate([self._P, 0.5 * (P + transposed(P))])
        for s in snaps:
            self._ids.append(int(s.id))
            self._kinds.append(s.kind)
            self._labels.append(s.label)
            self._states.append(TrackState(s.state))
            self._hits.append(int(s.hits))
            self._first.append(float(s.first_seen))
            self._last.append(float(s.last_seen))
            self._score.append(0.0)
            self._height.append(0.0)  # used by tentative tracks only
            self._moved.append(float(s.last_seen))
            self._gap.append(0.0)  # used by tentative tracks only
        self._next_id = max(self._next_id, max(ids) + 1)
        return self._manage()[0]

    # -- one camera frame ----------------------------------------------------------------------

    def update(
        self,
        camera: Hashable,
        t: float,
        pixels: ArrayLike,
        pixel_cov: ArrayLike | None = None,
        *,
        heights: ArrayLike = 0.0,
        kinds: Sequence[str | None] | str | None = None,
        labels: Sequence[str | None] | str | None = None,
        pixel_sigma: float = 1.0,
        appearances: ArrayLike | None = None,
    ) -> FrameResult:
        """Return what one frame of camera `camera` at time t (s) did to the tracks.

        pixels: (D, 2) distorted pixels of D detections (D = 0: the camera saw nothing);
        pixel_cov: (D, 2, 2) or (2, 2) px^2, or None for pixel_sigma^2 I; heights: (D,) or one
        value, metres above the floor of the point each pixel measures; kinds: "robot",
        "person", "unknown" or None (unknown) per detection; labels: an identity the sender is
        sure of (e.g. "robot" for the one robot's marker), or None; appearances: (D, F)
        non-negative descriptors of the detections' looks (core.localization.appearance), a row
        of zeros where one has none, or None (module docstring, "Appearance").
        Predicts the tracks to t, associates, updates (EKF), starts tracks, and moves the life
        cycle on (module docstring).
        """
        if camera not in self.cameras:
            known = ", ".join(repr(k) for k in self.cameras) or "none"
            raise InvalidInput(f"unknown camera {camera!r}; the tracker's cameras: {known}")
        t = check_time(t)
        cam = self.cameras[camera]
        px, R, h, kind, lab = self._parse(pixels, pixel_cov, heights, kinds, labels, pixel_sigma)
        look = _as_looks(appearances, px.shape[0])
        gap = self._frame_gap(camera, t)
        R, floor_std = self._with_camera_error(cam, px, R, h)
        n_all = px.shape[0]
        used = np.flatnonzero(
            (
                (floor_std <= self.config.located_std)
                | (self.config.located_std == 0)
                | np.array([v is not None for v in lab], dtype=bool)
            )
            & ~self._inside_a_robot(cam, t, px, R, h, kind)
        )
        left_out = np.setdiff1d(np.arange(n_all), used)
        vague = (px[left_out], R[left_out], h[left_out])
        if used.size < n_all:
            px, R, h = px[used], R[used], h[used]
            kind = [kind[j] for j in used.tolist()]
            lab = [lab[j] for j in used.tolist()]
            look = None if look is None else look[used]
        self._x, self._P = self._predicted(t)
        self._t = t
        n = px.shape[0]
        track_ids = np.full(n, -1, dtype=np.int64)
        started = np.zeros(n, dtype=bool)
        touched: list[int] = []
        n_old = len(self._ids)
        hit = np.zeros(n_old, dtype=bool)
        if n:
            rows, cols, loglik, ambiguous = self._associate(camera, px, R, h, kind, lab, look)
            if rows.size:
                # An ambiguous detection is skipped only while its track is fresh: past
                # `ambiguity_coast` the track's own prediction is no better than the choice.
                moved = np.array([self._moved[i] for i in rows.tolist()])
                sure = ~ambiguous | (t - moved > self.config.ambiguity_coast)
                # A track too vague to linearise about (a labelled body back after a long
                # absence) starts again at its detection, keeping its id.
                lost = self._vague(rows)
                if (sure & lost).any():
                    self._restart(
                        cam, rows[sure & lost], px[cols[sure & lost]], R, h, cols[sure & lost]
                    )
                upd = sure & ~lost
                if upd.any():
                    self._ekf_update(cam, rows[upd], px[cols[upd]], R[cols[upd]], h[cols[upd]])
                hit[rows] = True
                for i in rows[sure].tolist():
                    self._moved[i] = t
                if look is not None:
                    clear = ~ambiguous
                    for i, j in zip(rows[clear].tolist(), cols[clear].tolist(), strict=True):
                        self._looks.learn(self._ids[i], camera, look[j], self._x[i])
                gain = np.log(self.config.p_detect / self.config.clutter_density) + loglik
                for i, j, g in zip(rows.tolist(), cols.tolist(), gain.tolist(), strict=True):
                    if self._states[i] is TrackState.TENTATIVE:
                        self._score[i] += g
                    self._height[i] = float(h[j])
                    self._hits[i] += 1
                    self._last[i] = t
                    self._looks.moved(self._ids[i], self._x[i])
                    self._gap[i] = gap
                    if self._states[i] is TrackState.COASTING:
                        self._states[i] = TrackState.CONFIRMED
                    if self._kinds[i] == "unknown" and kind[j] != "unknown":
                        self._kinds[i] = kind[j]
                    track_ids[j] = self._ids[i]
                    touched.append(self._ids[i])
            free = np.setdiff1d(np.arange(n), cols)
        self._score_misses(cam, hit, vague)
        if n:
            if free.size:
                for j, tid in self._births(cam, free, px, R, h, kind, lab, gap):
                    track_ids[j] = tid
                    started[j] = True
                    touched.append(tid)
                    if look is not None:
                        self._looks.learn(tid, camera, look[j], self._x[-1])
        self._recognised_ids = []
        ended, dropped = self._manage()
        touched += self._recognised_ids
        index = {tid: i for i, tid in enumerate(self._ids)}
        updated = tuple(
            self._snapshot(index[tid], self._x, self._P, t) for tid in touched if tid in index
        )
        if used.size < n_all:
            all_ids = np.full(n_all, -1, dtype=np.int64)
            all_started = np.zeros(n_all, dtype=bool)
            all_ids[used], all_started[used] = track_ids, started
            track_ids, started = all_ids, all_started
        return FrameResult(t, camera, track_ids, started, updated, ended, dropped)

    def _parse(
        self,
        pixels: ArrayLike,
        pixel_cov: ArrayLike | None,
        heights: ArrayLike,
        kinds: Sequence[str | None] | str | None,
        labels: Sequence[str | None] | str | None,
        pixel_sigma: float,
    ) -> tuple[Array, Array, Array, list[str], list[str | None]]:
        try:
            px = np.array(pixels, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInput(f"pixels must be numeric, shape (D, 2): {exc}") from None
        if px.size == 0:
            px = px.reshape(0, 2)
        if px.ndim != 2 or px.shape[1] != 2:
            raise InvalidInput(f"pixels must have shape (D, 2), got {px.shape}")
        if not np.all(np.isfinite(px)):
            raise InvalidInput("pixels contain NaN or infinite values")
        n = px.shape[0]
        if pixel_cov is None:
            sigma = float(pixel_sigma)
            if not math.isfinite(sigma) or sigma <= 0:
                raise InvalidInput(f"pixel_sigma must be a positive number of pixels, got {sigma}")
            R = np.broadcast_to(np.eye(2) * sigma**2, (n, 2, 2)).copy()
        else:
            R = _as_covariances(pixel_cov, n, "pixel_cov")
        try:
            h = np.array(heights, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInput(f"heights must be numeric metres: {exc}") from None
        if h.ndim == 0:
            h = np.full(n, float(h))
        if h.shape != (n,) or not np.all(np.isfinite(h)) or np.any(np.abs(h) > 10.0):
            raise InvalidInput(f"heights must be {n} finite values in [-10, 10] m, one per pixel")
        kind = [k or "unknown" for k in _as_strings(kinds, n, "kinds", KINDS)]
        lab = _as_strings(labels, n, "labels")
        named = [v for v in lab if v is not None]
        if len(named) != len(set(named)):
            raise InvalidInput("a camera frame holds the same label twice")
        return px, R, h, kind, lab

    def _inside_a_robot(
        self, cam: NetworkCamera, t: float, px: Array, R: Array, h: Array, kind: list[str]
    ) -> NDArray[np.bool_]:
        """Return which detections are "person" ones whose floor point lies within
        `body_radius` of a robot's confirmed track at time t: a camera that missed the robot's
        marker fits its body (with a person beside it, or its mast) as a person, and nobody
        stands inside the robot. Such detections are left out like vague ones."""
        out = np.zeros(px.shape[0], dtype=bool)
        robots = [
            i
            for i, (k, st) in enumerate(zip(self._kinds, self._states, strict=True))
            if k == "robot" and st is not TrackState.TENTATIVE
        ]
        person = np.array([k == "person" for k in kind], dtype=bool)
        if not robots or not person.any():
            return out
        x, _ = self._predicted(t)
        where = x[robots, :2]
        for value in np.unique(h[person]):
            sel = np.flatnonzero(person & (h == value))
            try:
                est = locate_monocular(cam, px[sel], float(value), pixel_cov=R[sel])
            except InvalidInput:
                continue
            d = np.linalg.norm(est.xy[:, None] - where[None], axis=2)  # NaN: ray missed
            out[sel] = np.any(np.nan_to_num(d, nan=np.inf) < self.config.body_radius, axis=1)
        return out

    def _with_camera_error(
        self, cam: NetworkCamera, px: Array, R: Array, h: Array
    ) -> tuple[Array, Array]:
        """Return the pixel covariances R (D, 2, 2) plus the camera's calibration error
        (camera_error_std on the floor, through d pixel / d(x, y) where the pixel meets its
        height's plane), and each detection's floor position standard deviation from its pixel
        covariance (larger axis, m; inf where the ray misses its plane)."""
        sigma = self.config.camera_error_std
        floor_std = np.full(px.shape[0], np.inf)
        if px.shape[0] == 0:
            return R, floor_std
        out = R.copy()
        for value in np.unique(h):
            sel = np.flatnonzero(h == value)
            try:
                est = locate_monocular(cam, px[sel], float(value), pixel_cov=R[sel])
            except InvalidInput:
                continue  # a ray that misses the plane: the association refuses it anyway
            xy = est.xy
            # A pixel whose ray misses the plane has no floor point: nothing to add there.
            ok = np.all(np.isfinite(xy), axis=1)
            worst = largest_variance(est.cov)
            floor_std[sel[ok]] = np.sqrt(np.maximum(worst[ok], 0.0))
            if sigma <= 0:
                continue
            if not ok.any():
                continue
            proj = project_plane(cam, xy[ok], float(value), jacobian=True)
            assert proj.jacobian is not None
            J = proj.jacobian
            add = sigma**2 * (J @ transposed(J))
            good = np.all(np.isfinite(add), axis=(1, 2))
            out[sel[ok][good]] += add[good]
        return out, floor_std

    def _project(self, cam: NetworkCamera, h: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
        """Return every track projected at each detection's height: pixels (T, D, 2), the
        Jacobians d pixel / d(x, y) (T, D, 2, 2) and whether the camera can see the point
        (T, D): in front and within the field of view. The last matters: outside the field of
        view the distortion polynomial folds points back into the image, where a track could
        take a detection that is not its own."""
        T, D = len(self._ids), h.size
        u = np.empty((T, D, 2))
        J = np.empty((T, D, 2, 2))
        seen = np.empty((T, D), dtype=bool)
        xy = self._x[:, :2]
        for value in np.unique(h):
            sel = np.flatnonzero(h == value)
            proj = project_plane(cam, xy, float(value), jacobian=True)
            assert proj.jacobian is not None
            u[:, sel] = proj.pixels[:, None]
            J[:, sel] = proj.jacobian[:, None]
            Xc = np.column_stack([xy, np.full(T, float(value))]) @ cam.R.T + cam.t
            z = np.where(Xc[:, 2] > 1e-6, Xc[:, 2], 1.0)
            r2 = (Xc[:, 0] ** 2 + Xc[:, 1] ** 2) / z**2
            ok = (Xc[:, 2] > 1e-6) & (r2 <= cam.fov_radius**2)
            seen[:, sel] = ok[:, None]
        return u, J, seen

    def _associate(
        self,
        camera: Hashable,
        px: Array,
        R: Array,
        h: Array,
        kind: list[str],
        lab: list[str | None],
        look: Array | None,
    ) -> tuple[NDArray[np.intp], NDArray[np.intp], Array, NDArray[np.bool_]]:
        """Return the (track rows, detection columns) of this frame's assignment, each pair's
        log-likelihood ln N(nu; 0, S), and whether the pair is ambiguous (`_ambiguous`)."""
        T, D = len(self._ids), px.shape[0]
        if T == 0:
            empty = np.zeros(0, dtype=np.intp)
            return empty, empty, np.zeros(0), np.zeros(0, dtype=bool)
        cam = self.cameras[camera]
        u, J, front = self._project(cam, h)
        S = J @ self._P[:, None, :2, :2] @ transposed(J) + R[None]
        d2, logdet = mahalanobis(px[None] - u, S)
        cost = d2 + logdet + self._look_cost(camera, look)
        tk = np.array(self._kinds, dtype=object)
        dk = np.array(kind, dtype=object)
        compatible = (tk[:, None] == dk[None, :]) | (tk[:, None] == "unknown")
        compatible |= (dk == "unknown")[None, :]
        ok = front & np.isfinite(d2) & compatible
        tl = np.array(self._labels, dtype=object)
        dl = np.array(lab, dtype=object)
        det_labelled = np.array([v is not None for v in lab], dtype=bool)
        trk_labelled = np.array([v is not None for v in self._labels], dtype=bool)
        # A label says which target it is: only that track, and no gate.
        same_label = (tl[:, None] == dl[None, :]) & det_labelled[None, :]
        # An unlabelled track too vague to say where its body is takes nothing: it is ending.
        ok &= ~(self._vague(np.arange(T)) & ~trk_labelled)[:, None]
        gated = ok & (d2 <= self.config.gate) & ~det_labelled[None, :] & ~trk_labelled[:, None]
        if self.occluders is not None:
            # A camera does not see through walls: a track it cannot see takes nothing of it
            # (a vague track in the next room would otherwise take a detection through one).
            gated &= self._visible(cam)[:, None]
        rows_out: list[NDArray[np.intp]] = []
        cols_out: list[NDArray[np.intp]] = []
        free_rows = np.ones(T, dtype=bool)
        free_cols = np.ones(D, dtype=bool)
        mature = np.array([s is not TrackState.TENTATIVE for s in self._states], dtype=bool)
        rounds = (ok & same_label, gated & mature[:, None], gated & ~mature[:, None])
        ambiguous_out: list[NDArray[np.bool_]] = []
        for k, allowed in enumerate(rounds):
            allowed = allowed & free_rows[:, None] & free_cols[None, :]
            r, c = assign_pairs(cost, allowed)
            free_rows[r] = False
            free_cols[c] = False
            rows_out.append(r)
            cols_out.append(c)
            ambiguous_out.append(
                ambiguous_pairs(cost, rounds[1], r, c, self.config.ambiguity)
                if k == 1
                else np.zeros(r.size, dtype=bool)
            )
        rows, cols = np.concatenate(rows_out), np.concatenate(cols_out)
        loglik = -0.5 * (d2[rows, cols] + logdet[rows, cols]) - math.log(2.0 * math.pi)
        return rows, cols, loglik, np.concatenate(ambiguous_out)

    def _look_cost(self, camera: Hashable, look: Array | None) -> Array | float:
        """Return the appearance term (T, D) of the assignment costs (module docstring,
        "Appearance"): appearance_weight times the distance between each detection's
        descriptor and each track's in `camera`; 0 where either has none."""
        weight = self.config.appearance_weight
        if look is None or weight == 0:
            return 0.0
        return np.nan_to_num(weight * self._looks.distances(self._ids, camera, look), nan=0.0)

    def _visible(self, cam: NetworkCamera) -> NDArray[np.bool_]:
        """Return whether `cam` has a clear line of sight (past the occluders) to some of each
        track's body: the top of its axis, body_height (a robot: the height of its last
        detection), as a camera that sees any of a body may detect it, at the predicted
        position or at any of four points around it, body_radius plus up to 0.3 m of its
        position's uncertainty (two standard deviations) away: a body beside a tall cabinet
        whose prediction falls just behind it is still seen."""
        assert self.occluders is not None
        T = len(self._ids)
        z = np.array(
            [
                hh if k == "robot" else self.config.body_height
                for k, hh in zip(self._kinds, self._height, strict=True)
            ]
        )
        spread = 2.0 * np.sqrt(np.maximum(largest_variance(self._P[:, :2, :2]), 0.0))
        r = self.config.body_radius + np.minimum(spread, 0.3)
        ring = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
        xy = self._x[:, None, :2] + r[:, None, None] * ring[None]  # (T, 5, 2)
        pts = np.concatenate([xy, np.broadcast_to(z[:, None, None], (T, 5, 1))], axis=2)
        clear = line_of_sight(cam.center[None], pts.reshape(-1, 3), self.occluders)[0]
        return np.asarray(clear.reshape(T, 5).any(axis=1), dtype=bool)

    def _vague(self, rows: NDArray[np.intp]) -> NDArray[np.bool_]:
        """Return whether each track's position standard deviation (larger axis) exceeds
        `max_position_std`."""
        return largest_variance(self._P[rows, :2, :2]) > self.config.max_position_std**2

    def _restart(
        self,
        cam: NetworkCamera,
        rows: NDArray[np.intp],
        px: Array,
        R: Array,
        h: Array,
        cols: NDArray[np.intp],
    ) -> None:
        """Put tracks `rows` at their detections' back-projections, speed unknown."""
        for i, z, j in zip(rows.tolist(), px, cols.tolist(), strict=True):
            est = locate_monocular(cam, z[None], float(h[j]), pixel_cov=R[j][None])
            if not est.valid[0]:
                continue
            self._x[i] = [est.xy[0, 0], est.xy[0, 1], 0.0, 0.0]
            self._P[i] = 0.0
            self._P[i, :2, :2] = est.cov[0]
            self._P[i, 2, 2] = self._P[i, 3, 3] = self.config.initial_speed_std**2

    def _score_misses(
        self, cam: NetworkCamera, hit: NDArray[np.bool_], vague: tuple[Array, Array, Array]
    ) -> None:
        """Add ln(1 - p_D) to the score of each tentative track that this camera has in view
        (at the height of its last detection, not hidden by the occluders nor by another body:
        `_behind_a_body`) but did not detect in this frame. A track inside the gate of a
        detection left out as too vague (`vague`: its pixels, covariances and heights) was seen,
        only not placed: no miss either."""
        idx = [i for i in range(hit.size) if not hit[i] and self._states[i] is TrackState.TENTATIVE]
        if not idx:
            return
        rows = np.asarray(idx, dtype=np.intp)
        heights = np.asarray([self._height[i] for i in idx])
        pts = np.column_stack([self._x[rows, :2], heights])
        seen = cam.in_view(pts)
        if self.occluders is not None and seen.any():
            seen[seen] = line_of_sight(cam.center[None], pts[seen], self.occluders)[0]
        if seen.any():
            seen[seen] = ~self._behind_a_body(cam, rows[seen])
        v_px, v_R, v_h = vague
        if seen.any() and v_px.shape[0]:
            for value in np.unique(v_h):
                sel = np.flatnonzero(v_h == value)
                look = rows[seen]
                proj = project_plane(cam, self._x[look, :2], float(value), jacobian=True)
                assert proj.jacobian is not None
                J = proj.jacobian
                S = J[:, None] @ self._P[look][:, None, :2, :2] @ transposed(J)[:, None]
                d2, _ = mahalanobis(v_px[sel][None] - proj.pixels[:, None], S + v_R[sel][None])
                inside = np.any(np.nan_to_num(d2, nan=np.inf) <= self.config.gate, axis=1)
                seen[np.flatnonzero(seen)[inside]] = False
        miss = math.log(1.0 - self.config.p_detect)
        for i in rows[seen].tolist():
            self._score[i] += miss

    def _behind_a_body(self, cam: NetworkCamera, rows: NDArray[np.intp]) -> NDArray[np.bool_]:
        """Return whether each track of `rows` stands behind another track's body as `cam`
        sees it: on the floor, the other is nearer the camera, within two body radii of the
        line of sight at its own range, and near enough that its body (body_height tall) hides
        some of this one (from a camera at height H, a body at range d covers the floor out to
        d H / (H - body_height)). Robots are too low to hide anybody, and a lost track
        (`_waiting`) stands nowhere."""
        cfg = self.config
        others = np.array([k != "robot" for k in self._kinds], dtype=bool)
        others &= ~self._waiting(np.arange(len(self._ids)))
        out = np.zeros(rows.size, dtype=bool)
        if others.sum() == 0:
            return out
        c = cam.center[:2]
        H = float(cam.center[2])
        a = self._x[rows, :2] - c  # (n, 2)
        b = self._x[others, :2] - c  # (m, 2)
        da = np.linalg.norm(a, axis=1)
        db = np.linalg.norm(b, axis=1)
        reach = db * H / (H - cfg.body_height) if H > cfg.body_height else np.full(db.shape, np.inf)
        along = a @ b.T / np.maximum(da[:, None], 1e-9)  # (n, m) b's range along a's sight line
        across = np.abs(a[:, 0:1] * b[None, :, 1] - a[:, 1:2] * b[None, :, 0]) / np.maximum(
            da[:, None], 1e-9
        )
        nearer = (db[None] < da[:, None] - 1e-6) & (along > 0)
        covers = (across < 2.0 * cfg.body_radius) & (da[:, None] <= reach[None])
        out = np.any(nearer & covers, axis=1)
        return out

    def _ekf_update(
        self, cam: NetworkCamera, rows: NDArray[np.intp], z: Array, R: Array, h: Array
    ) -> None:
        """Update tracks `rows` with one pixel each (EKF, Joseph form), vectorised."""
        x = self._x[rows]
        P = self._P[rows]
        u = np.empty((rows.size, 2))
        H = np.zeros((rows.size, 2, 4))
        for value in np.unique(h):
            sel = np.flatnonzero(h == value)
            proj = project_plane(cam, x[sel, :2], float(value), jacobian=True)
            assert proj.jacobian is not None
            u[sel] = proj.pixels
            H[sel, :, :2] = proj.jacobian
        Ht = transposed(H)
        S = H @ P @ Ht + R
        S_inv, _ = inv2(S)
        K = P @ Ht @ S_inv  # (n, 4, 2)
        x = x + np.einsum("nij,nj->ni", K, z - u)
        IKH = np.eye(4)[None] - K @ H
        P = IKH @ P @ transposed(IKH) + K @ R @ transposed(K)
        self._x[rows] = x
        self._P[rows] = 0.5 * (P + transposed(P))

    def _frame_gap(self, camera: Hashable, t: float) -> float:
        """Record a frame of `camera` at t (s); return the running mean of its frame intervals
        (s; 0 before its second frame): the mean of the previous mean and the newest interval,
        intervals over MAX_FRAME_GAP left out (a silence, not a frame rate)."""
        last = self._camera_last.get(camera)
        self._camera_last[camera] = t
        if last is not None and 0.0 < t - last <= MAX_FRAME_GAP:
            old = self._camera_gap.get(camera)
            self._camera_gap[camera] = t - last if old is None else 0.5 * (old + t - last)
        return self._camera_gap.get(camera, 0.0)

    def _births(
        self,
        cam: NetworkCamera,
        free: NDArray[np.intp],
        px: Array,
        R: Array,
        h: Array,
        kind: list[str],
        lab: list[str | None],
        gap: float,
    ) -> list[tuple[int, int]]:
        """Start tentative tracks at the free detections that are no existing body; return
        (detection index, new id) pairs (`gap`: the camera's frame interval, `_frame_gap`).
        The most precise detections go first, each checked against every track, those it just
        started included."""
        cfg = self.config
        xy = np.full((px.shape[0], 2), np.nan)
        C = np.broadcast_to(np.eye(2), (px.shape[0], 2, 2)).copy()
        for value in np.unique(h[free]):
            sel = free[h[free] == value]
            est = locate_monocular(cam, px[sel], float(value), pixel_cov=R[sel])
            v = est.valid
            xy[sel[v]] = est.xy[v]
            C[sel[v]] = est.cov[v]
        out: list[tuple[int, int]] = []
        order = free[np.argsort(np.linalg.det(R[free]), kind="stable")]
        for j in order.tolist():
            if not np.all(np.isfinite(xy[j])):
                continue
            if lab[j] is not None and lab[j] in self._labels:
                continue
            if self._ids and lab[j] is None:
                # Only a body this camera can see may have made this blob as its outlier.
                T = len(self._ids)
                near = self._visible(cam) if self.occluders is not None else np.ones(T, bool)
                # A lost track waiting to be recognised (module docstring) stands nowhere.
                near &= ~self._waiting(np.arange(T))
                diff = xy[j] - self._x[near, :2]
                if np.any(np.einsum("ij,ij->i", diff, diff) < cfg.min_separation**2):
                    continue
                d2, _ = mahalanobis(diff, self._P[near, :2, :2] + C[j])
                if np.any(d2 <= cfg.birth_gate):
                    continue
            out.append((j, self._birth(xy[j], C[j], kind[j], lab[j], float(h[j]), gap)))
        return out

    def _birth(
        self, xy: Array, C: Array, kind: str, label: str | None, height: float, gap: float
    ) -> int:
        x = np.array([xy[0], xy[1], 0.0, 0.0])
        P = np.zeros((4, 4))
        P[:2, :2] = C
        P[2, 2] = P[3, 3] = self.config.initial_speed_std**2
        tid = self._next_id
        self._next_id += 1
        t = float(self._t) if self._t is not None else 0.0
        self._x = np.concatenate([self._x, x[None]])
        self._P = np.concatenate([self._P, P[None]])
        self._ids.append(tid)
        self._kinds.append(kind)
        self._labels.append(label)
        # A label is an identity the sender is sure of: nothing left to confirm.
        confirmed = self.config.confirm_hits <= 1 or label is not None
        self._states.append(TrackState.CONFIRMED if confirmed else TrackState.TENTATIVE)
        self._hits.append(1)
        self._first.append(t)
        self._last.append(t)
        self._score.append(0.0)
        self._height.append(height)
        self._moved.append(t)
        self._gap.append(gap)
        return tid

    def _waiting(self, rows: NDArray[np.intp]) -> NDArray[np.bool_]:
        """Return whether each track of `rows` is lost and waiting to be recognised by its
        look: unlabelled, with a look, too vague to say where its body is."""
        has_look = np.array(
            [self._ids[i] in self._looks and self._labels[i] is None for i in rows.tolist()],
            dtype=bool,
        )
        return has_look & self._vague(rows)

    def _recognised(self, i: int) -> int | None:
        """Return the lost track (`_waiting`) that the newly confirmed track i is the body
        of, or None: of those whose look in a camera both were seen by lies within
        recognition_distance of track i's and whose position's uncertainty holds track i's
        position (squared Mahalanobis distance within the gate), the nearest in look."""
        if self._ids[i] not in self._looks:
            return None
        rows = np.arange(len(self._ids))
        waiting = self._waiting(rows)
        best, best_d = None, self.config.recognition_distance
        for j in np.flatnonzero(waiting).tolist():
            if j == i or self._kinds[j] not in (self._kinds[i], "unknown"):
                continue
            d = self._looks.distance(self._ids[i], self._ids[j])
            was = self._looks.last_position(self._ids[j])
            if d is None or was is None or d > best_d:
                continue
            # A walker covers at most WALKING_SPEED in each second since the lost track's last
            # update, plus three standard deviations of where the new track puts them.
            reach = WALKING_SPEED * (self._first[i] - self._last[j]) + 3.0 * math.sqrt(
                float(largest_variance(self._P[i, :2, :2]))
            )
            if float(np.linalg.norm(self._x[i, :2] - was)) <= reach:
                best, best_d = j, d
        return best

    def _take_over(self, j: int, i: int) -> None:
        """Let lost track j go on as the newly confirmed track i, which it is the body of
        (`_recognised`): track j takes track i's state, sightings and looks."""
        self._x[j] = self._x[i]
        self._P[j] = self._P[i]
        self._states[j] = TrackState.CONFIRMED
        self._hits[j] += self._hits[i]
        self._last[j] = self._last[i]
        self._moved[j] = self._moved[i]
        self._height[j] = self._height[i]
        self._gap[j] = self._gap[i]
        self._looks.inherit(self._ids[j], self._ids[i])
        self._recognised_ids.append(self._ids[j])

    def _manage(self) -> tuple[tuple[TrackSnapshot, ...], tuple[int, ...]]:
        """Move the life cycle on at the tracker's time; return (ended, dropped ids)."""
        cfg = self.config
        t = float(self._t) if self._t is not None else 0.0
        keep = np.ones(len(self._ids), dtype=bool)
        ended: list[TrackSnapshot] = []
        dropped: list[int] = []
        gap = self._gap
        for i, st in enumerate(self._states):
            silent = t - self._last[i]
            if st is TrackState.TENTATIVE:
                if self._hits[i] >= cfg.confirm_hits and self._score[i] >= cfg.confirm_score:
                    self._states[i] = TrackState.CONFIRMED
                    j = self._recognised(i)
                    if j is not None:
                        self._take_over(j, i)
                        keep[i] = False
                        dropped.append(self._ids[i])
                elif (
                    t - self._first[i] > max(cfg.confirm_window, CONFIRM_GAPS * gap[i])
                    or silent > max(cfg.tentative_timeout, TENTATIVE_GAPS * gap[i])
                    or self._score[i] < cfg.drop_score
                ):
                    keep[i] = False
                    dropped.append(self._ids[i])
                continue
            if silent > cfg.coast_after:
                self._states[i] = TrackState.COASTING
            if self._states[i] is TrackState.COASTING:
                worst = float(largest_variance(self._P[i, :2, :2]))
                if self._labels[i] is not None:
                    # A labelled body is known by its label, not found by its position: its
                    # track waits for the label to come back however vague it has become.
                    over = silent > cfg.labelled_end_after
                elif self._ids[i] in self._looks:
                    # A body with a look may be recognised by it (module docstring).
                    over = silent > cfg.end_after
                else:
                    over = silent > cfg.end_after or worst > cfg.max_position_std**2
                if over:
                    self._states[i] = TrackState.ENDED
                    ended.append(self._snapshot(i, self._x, self._P, t))
                    keep[i] = False
        if not keep.all():
            idx = np.flatnonzero(keep)
            self._x = self._x[idx]
            self._P = self._P[idx]
            for name in (
                "_ids",
                "_kinds",
                "_labels",
                "_states",
                "_hits",
                "_first",
                "_last",
                "_score",
                "_height",
                "_moved",
                "_gap",
            ):
                old = getattr(self, name)
                setattr(self, name, [old[i] for i in idx.tolist()])
            self._looks.forget((*dropped, *(snap.id for snap in ended)))
        return tuple(ended), tuple(dropped)
