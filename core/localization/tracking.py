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

This module holds the loop (predict, associate, update); each rule above lives in a module named
for it: the tracks' table (track_table), a frame's checks (frame_detections), the assignment
(association), what a camera can see (occlusion), births and misses (births), the life cycle
(life_cycle), looks (looks) and recognition (recognition), stored tracks (track_restore).
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
    mahalanobis,
    project_tracks,
)
from core.localization.births import births, restart, score_misses
from core.localization.cameras import NetworkCamera
from core.localization.frame_detections import (
    as_looks,
    inside_a_robot,
    parse_frame,
    with_camera_error,
)
from core.localization.life_cycle import move_life_cycle
from core.localization.looks import TrackLooks
from core.localization.motion import cv_process_noise, cv_transition
from core.localization.occluders import Occluders
from core.localization.occlusion import visible
from core.localization.track_restore import restored_states
from core.localization.track_table import TrackTable
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
        self._tracks = TrackTable()
        # Each camera's last frame time and the running mean of its frame intervals (s); each
        # track's interval of the camera that last updated it (module docstring, life cycle).
        self._camera_last: dict[Hashable, float] = {}
        self._camera_gap: dict[Hashable, float] = {}
        # Each track's look (module docstring, "Appearance").
        self._looks = TrackLooks(self.config.appearance_rate)

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
        return len(self._tracks)

    def tracks(
        self, t: float | None = None, *, states: Sequence[TrackState] | None = None
    ) -> tuple[TrackSnapshot, ...]:
        """Return snapshots of the tracks in `states` (all when None), predicted to time t (s)
        if given (the tracker itself is not moved)."""
        x, P, when = self._tracks.x, self._tracks.P, self._t
        if t is not None:
            t = check_time(t)
            x, P = self._predicted(t)
            when = t
        keep = None if states is None else set(states)
        return tuple(
            self._tracks.snapshot(i, x, P, when)
            for i in range(len(self._tracks))
            if keep is None or self._tracks.states[i] in keep
        )

    def _predicted(self, t: float) -> tuple[Array, Array]:
        """Return every track's state (T, 4) and covariance (T, 4, 4) predicted to time t."""
        if self._t is None:
            return self._tracks.x, self._tracks.P
        dt = t - self._t
        if dt < 0:
            raise InvalidInput(
                f"time went backwards: t = {t} s is before the tracker's time {self._t} s; "
                "feed frames in time order (ReorderBuffer sorts frames that arrive late)"
            )
        if dt == 0 or not self._tracks.ids:
            return self._tracks.x, self._tracks.P
        F = cv_transition(dt)
        x = self._tracks.x @ F.T
        P = F @ self._tracks.P @ F.T + cv_process_noise(dt, self.config.q)
        return x, P

    def advance(self, t: float) -> tuple[TrackSnapshot, ...]:
        """Move every track to time t (s) without a measurement; return the tracks that ended."""
        t = check_time(t)
        self._tracks.x, self._tracks.P = self._predicted(t)
        self._t = t
        return self._manage()[0]

    def shift(self, dt: float) -> None:
        """Move the tracker's clock and every track's times on by dt seconds without any
        motion or added uncertainty: a pause of the cameras' world (the twin held still), so
        that its tracks neither coast nor end over it."""
        dt = check_time(dt)
        if dt < 0:
            raise InvalidInput(f"a shift must not go back in time, got {dt} s")
        if self._t is not None:
            self._t += dt
        self._tracks.shift(dt)
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
        x, P = restored_states(snaps, t, self.config.q, self._tracks.ids)
        self._tracks.x, self._tracks.P = self._predicted(t)
        self._t = t
        if not snaps:
            return self._manage()[0]
        self._tracks.x = np.concatenate([self._tracks.x, x])
        self._tracks.P = np.concatenate([self._tracks.P, P])
        for s in snaps:
            # Height and frame interval are used by tentative tracks only.
            self._tracks.append(
                int(s.id),
                s.kind,
                s.label,
                TrackState(s.state),
                hits=int(s.hits),
                first=float(s.first_seen),
                last=float(s.last_seen),
                height=0.0,
                moved=float(s.last_seen),
                gap=0.0,
            )
        self._next_id = max(self._next_id, max(int(s.id) for s in snaps) + 1)
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
        px, R, h, kind, lab = parse_frame(pixels, pixel_cov, heights, kinds, labels, pixel_sigma)
        look = as_looks(appearances, px.shape[0])
        gap = self._frame_gap(camera, t)
        R, floor_std = with_camera_error(cam, px, R, h, self.config.camera_error_std)
        n_all = px.shape[0]
        used = np.flatnonzero(
            (
                (floor_std <= self.config.located_std)
                | (self.config.located_std == 0)
                | np.array([v is not None for v in lab], dtype=bool)
            )
            & ~inside_a_robot(cam, px, R, h, kind, self._robots_at(t), self.config.body_radius)
        )
        left_out = np.setdiff1d(np.arange(n_all), used)
        vague = (px[left_out], R[left_out], h[left_out])
        if used.size < n_all:
            px, R, h = px[used], R[used], h[used]
            kind = [kind[j] for j in used.tolist()]
            lab = [lab[j] for j in used.tolist()]
            look = None if look is None else look[used]
        self._tracks.x, self._tracks.P = self._predicted(t)
        self._t = t
        n = px.shape[0]
        track_ids = np.full(n, -1, dtype=np.int64)
        started = np.zeros(n, dtype=bool)
        touched: list[int] = []
        n_old = len(self._tracks)
        hit = np.zeros(n_old, dtype=bool)
        if n:
            rows, cols, loglik, ambiguous = self._associate(camera, px, R, h, kind, lab, look)
            if rows.size:
                # An ambiguous detection is skipped only while its track is fresh: past
                # `ambiguity_coast` the track's own prediction is no better than the choice.
                moved = np.array([self._tracks.moved[i] for i in rows.tolist()])
                sure = ~ambiguous | (t - moved > self.config.ambiguity_coast)
                # A track too vague to linearise about (a labelled body back after a long
                # absence) starts again at its detection, keeping its id.
                lost = self._tracks.vague(rows, self.config.max_position_std)
                if (sure & lost).any():
                    again = sure & lost
                    restart(cam, self._tracks, rows[again], (px, R, h), cols[again], self.config)
                upd = sure & ~lost
                if upd.any():
                    self._ekf_update(cam, rows[upd], px[cols[upd]], R[cols[upd]], h[cols[upd]])
                hit[rows] = True
                for i in rows[sure].tolist():
                    self._tracks.moved[i] = t
                if look is not None:
                    clear = ~ambiguous
                    for i, j in zip(rows[clear].tolist(), cols[clear].tolist(), strict=True):
                        self._looks.learn(self._tracks.ids[i], camera, look[j], self._tracks.x[i])
                gain = np.log(self.config.p_detect / self.config.clutter_density) + loglik
                for i, j, g in zip(rows.tolist(), cols.tolist(), gain.tolist(), strict=True):
                    if self._tracks.states[i] is TrackState.TENTATIVE:
                        self._tracks.score[i] += g
                    self._tracks.height[i] = float(h[j])
                    self._tracks.hits[i] += 1
                    self._tracks.last[i] = t
                    self._looks.moved(self._tracks.ids[i], self._tracks.x[i])
                    self._tracks.gap[i] = gap
                    if self._tracks.states[i] is TrackState.COASTING:
                        self._tracks.states[i] = TrackState.CONFIRMED
                    if self._tracks.kinds[i] == "unknown" and kind[j] != "unknown":
                        self._tracks.kinds[i] = kind[j]
                    track_ids[j] = self._tracks.ids[i]
                    touched.append(self._tracks.ids[i])
            free = np.setdiff1d(np.arange(n), cols)
        score_misses(cam, self._tracks, self._looks, self.occluders, self.config, hit, vague)
        if n:
            if free.size:
                born = births(
                    cam,
                    self._tracks,
                    self._looks,
                    self.occluders,
                    self.config,
                    (px, R, h, kind, lab),
                    free,
                    t=t,
                    gap=gap,
                    next_id=self._next_id,
                )
                self._next_id += len(born)
                for j, tid in born:
                    track_ids[j] = tid
                    started[j] = True
                    touched.append(tid)
                    if look is not None:
                        self._looks.learn(tid, camera, look[j], self._tracks.x[-1])
        ended, dropped, recognised = self._manage()
        touched += recognised
        index = {tid: i for i, tid in enumerate(self._tracks.ids)}
        updated = tuple(
            self._tracks.snapshot(index[tid], self._tracks.x, self._tracks.P, t)
            for tid in touched
            if tid in index
        )
        if used.size < n_all:
            all_ids = np.full(n_all, -1, dtype=np.int64)
            all_started = np.zeros(n_all, dtype=bool)
            all_ids[used], all_started[used] = track_ids, started
            track_ids, started = all_ids, all_started
        return FrameResult(t, camera, track_ids, started, updated, ended, dropped)

    def _robots_at(self, t: float) -> Array:
        """Return where the robots' confirmed or coasting tracks are at time t (R, 2), m."""
        robots = [
            i
            for i, (k, st) in enumerate(zip(self._tracks.kinds, self._tracks.states, strict=True))
            if k == "robot" and st is not TrackState.TENTATIVE
        ]
        if not robots:
            return np.zeros((0, 2))
        x, _ = self._predicted(t)
        return x[robots, :2]

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
        log-likelihood ln N(nu; 0, S), and whether the pair is ambiguous (`ambiguous_pairs`)."""
        T, D = len(self._tracks), px.shape[0]
        if T == 0:
            empty = np.zeros(0, dtype=np.intp)
            return empty, empty, np.zeros(0), np.zeros(0, dtype=bool)
        cam = self.cameras[camera]
        u, J, front = project_tracks(cam, self._tracks.x[:, :2], h)
        S = J @ self._tracks.P[:, None, :2, :2] @ transposed(J) + R[None]
        d2, logdet = mahalanobis(px[None] - u, S)
        cost = d2 + logdet + self._look_cost(camera, look)
        tk = np.array(self._tracks.kinds, dtype=object)
        dk = np.array(kind, dtype=object)
        compatible = (tk[:, None] == dk[None, :]) | (tk[:, None] == "unknown")
        compatible |= (dk == "unknown")[None, :]
        ok = front & np.isfinite(d2) & compatible
        tl = np.array(self._tracks.labels, dtype=object)
        dl = np.array(lab, dtype=object)
        det_labelled = np.array([v is not None for v in lab], dtype=bool)
        trk_labelled = np.array([v is not None for v in self._tracks.labels], dtype=bool)
        # A label says which target it is: only that track, and no gate.
        same_label = (tl[:, None] == dl[None, :]) & det_labelled[None, :]
        # An unlabelled track too vague to say where its body is takes nothing: it is ending.
        vague = self._tracks.vague(np.arange(T), self.config.max_position_std)
        ok &= ~(vague & ~trk_labelled)[:, None]
        gated = ok & (d2 <= self.config.gate) & ~det_labelled[None, :] & ~trk_labelled[:, None]
        if self.occluders is not None:
            # A camera does not see through walls: a track it cannot see takes nothing of it
            # (a vague track in the next room would otherwise take a detection through one).
            gated &= visible(cam, self._tracks, self.occluders, self.config)[:, None]
        rows_out: list[NDArray[np.intp]] = []
        cols_out: list[NDArray[np.intp]] = []
        free_rows = np.ones(T, dtype=bool)
        free_cols = np.ones(D, dtype=bool)
        mature = np.array([s is not TrackState.TENTATIVE for s in self._tracks.states], dtype=bool)
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
        return np.nan_to_num(
            weight * self._looks.distances(self._tracks.ids, camera, look), nan=0.0
        )

    def _ekf_update(
        self, cam: NetworkCamera, rows: NDArray[np.intp], z: Array, R: Array, h: Array
    ) -> None:
        """Update tracks `rows` with one pixel each (EKF, Joseph form), vectorised."""
        x = self._tracks.x[rows]
        P = self._tracks.P[rows]
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
        self._tracks.x[rows] = x
        self._tracks.P[rows] = 0.5 * (P + transposed(P))

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

    def _manage(self) -> tuple[tuple[TrackSnapshot, ...], tuple[int, ...], list[int]]:
        """Move the life cycle on at the tracker's time; return (ended, dropped ids, ids of
        the lost tracks recognised: core.localization.life_cycle)."""
        t = float(self._t) if self._t is not None else 0.0
        return move_life_cycle(self._tracks, self._looks, self.config, t)
