"""Multi-target tracking on the floor: constant-velocity Kalman filters with GNN association.

Each track is a target moving on the plane Z = h with the state s = (x, y, vx, vy) (m, m/s)
and its covariance P (4 x 4). Between frames the state follows the continuous white noise
acceleration model (Bar-Shalom, Li & Kirubarajan, "Estimation with Applications to Tracking and
Navigation", 2001, sec. 6.2.2): per axis

    F(dt) = [[1, dt], [0, 1]],    Q(dt) = q [[dt^3 / 3, dt^2 / 2], [dt^2 / 2, dt]],

with q the power spectral density of the acceleration (m^2 / s^3), so any time step, regular or
not, is one prediction s <- F s, P <- F P F^T + Q. A measurement is a floor position z (2,)
with its covariance R (2 x 2), H = [I 0]; the update is the Kalman filter's in Joseph form
(ibid. sec. 5.2), which keeps P symmetric positive definite in floating point.

Association per frame is global nearest neighbour: the cost of measurement j for track i is
d2 + ln det S, with d2 = nu^T S^-1 nu the squared Mahalanobis distance of the innovation
nu = z_j - H s_i (S = H P H^T + R), i.e. the negative log-likelihood up to a constant, so a
vague track does not win a detection over a precise one merely by its wide gate. Pairs with
d2 above the chi-square gate (2 dof; 9.21 keeps 99 % of true detections) are forbidden, and
scipy.optimize.linear_sum_assignment solves the rest, in rounds. First the measurements with a
label (e.g. "robot"): each can only go to the track with that label, and is not gated, as the
label already says which target it is. Then the unlabelled measurements, which may go to any
track (a missing label says nothing), to the confirmed tracks first and the tentative ones with
what is left, so that a track started by a false detection next to a target cannot take that
target's detection.

Track life: a measurement no track takes starts a tentative track (position from z, speed
unknown: N(0, `initial_speed_std`^2) per axis), unless it is so close to an existing track
(d2 below `birth_gate`) that it is that target's outlier rather than a new one. A tentative
track is confirmed when it has been updated in `confirm_hits` (M) of its first
`confirm_window` (N) frames, deleted otherwise; any track is deleted when it has not been
updated for more than `max_miss_time` seconds.

Two entry points per frame: `FloorTracker.update` takes floor positions (from the estimators
of core.localization.ground); `FloorTracker.update_detections` takes raw per-camera pixel
detections, associates them with the tracks camera by camera (reprojecting each predicted
track and its covariance into the image), fuses each track's cross-camera group by maximum
likelihood on the plane (`locate_ml`), and groups the leftover detections of different cameras
into new targets by the Mahalanobis consistency of their back-projections onto Z = h.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from core.errors import InvalidInput
from core.localization._checks import as_cameras, check_height
from core.localization._projection import inv2, project_plane, transposed
from core.localization.cameras import NetworkCamera
from core.localization.ground import FloorEstimate, locate_ml, locate_monocular

Array = NDArray[np.float64]

# Chi-square quantiles with 2 degrees of freedom: -2 ln(1 - p).
CHI2_2DOF_99 = 9.2103
CHI2_2DOF_999999 = 27.631
# Cost of a forbidden pairing: above any allowed cost, which is clipped below it.
_FORBIDDEN = 1e9
_MAX_COST = 1e8


class TrackStatus(StrEnum):
    """A track's stage: tentative until M of its first N frames hit, then confirmed."""

    TENTATIVE = "tentative"
    CONFIRMED = "confirmed"


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of a `FloorTracker`.

    q: acceleration power spectral density, m^2 / s^3 (about the squared change of speed per
    second a target makes: 0.1-1 for walking people). gate: squared Mahalanobis gate (chi-square,
    2 dof). birth_gate: a measurement within this squared distance of a track starts no new one.
    confirm_hits, confirm_window: M of N. max_miss_time: seconds without an update before a track
    is deleted. initial_speed_std: prior speed standard deviation per axis of a new track, m/s.
    height: Z of the tracked plane, metres (for pixel detections). history_length: how many
    (t, xy, cov) updates each track keeps.
    """

    q: float = 0.5
    gate: float = CHI2_2DOF_99
    birth_gate: float = CHI2_2DOF_999999
    confirm_hits: int = 3
    confirm_window: int = 5
    max_miss_time: float = 1.0
    initial_speed_std: float = 1.0
    height: float = 0.0
    history_length: int = 1000

    def __post_init__(self) -> None:
        for name in ("q", "gate", "birth_gate", "max_miss_time", "initial_speed_std"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
                raise InvalidInput(f"TrackerConfig.{name} must be a positive number, got {value!r}")
        check_height(self.height)
        for name in ("confirm_hits", "confirm_window", "history_length"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise InvalidInput(f"TrackerConfig.{name} must be an integer >= 1, got {value!r}")
        if self.confirm_hits > self.confirm_window:
            raise InvalidInput(
                f"confirm_hits (M = {self.confirm_hits}) cannot exceed confirm_window "
                f"(N = {self.confirm_window}): a track could never be confirmed"
            )


@dataclass(frozen=True)
class TrackPoint:
    """One update of a track: time t (s), filtered position xy (2,) m, its covariance (2, 2) m^2."""

    t: float
    xy: Array
    cov: Array


@dataclass(frozen=True)
class TrackSnapshot:
    """A track at time t: state (4,) = (x, y, vx, vy) in m and m/s, cov (4, 4), its status, the
    number of updates (`hits`), the time of the last one, and its past updates (`history`)."""

    id: int
    label: str | None
    status: TrackStatus
    t: float
    state: Array
    cov: Array
    hits: int
    last_update: float
    history: tuple[TrackPoint, ...] = field(repr=False)

    @property
    def xy(self) -> Array:
        """Position (2,), metres."""
        return self.state[:2]

    @property
    def xy_cov(self) -> Array:
        """Covariance of the position (2, 2), m^2."""
        return self.cov[:2, :2]

    @property
    def velocity(self) -> Array:
        """Velocity (2,), m/s."""
        return self.state[2:]


@dataclass(frozen=True)
class FrameAssociation:
    """What one frame did: `track_ids` (M,) the id of the track each measurement (or detection)
    updated or started, -1 when it was dropped (outside every gate yet too close to a track to
    start one, a second measurement of one label, or a detection that could not be located);
    `started` (M,) whether it started that track; `deleted` the ids of the tracks deleted."""

    t: float
    track_ids: NDArray[np.int64]
    started: NDArray[np.bool_]
    deleted: tuple[int, ...]


def cv_transition(dt: float) -> Array:
    """Return F(dt) (4, 4) of the constant-velocity model on (x, y, vx, vy): x <- x + dt vx."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    return F


def cv_process_noise(dt: float, q: float) -> Array:
    """Return Q(dt) (4, 4), m^2, m^2/s, m^2/s^2, of white acceleration of density q (m^2/s^3).

    Q = integral_0^dt F(s) G q G^T F(s)^T ds with G = [0 I]^T, which per axis is
    q [[dt^3/3, dt^2/2], [dt^2/2, dt]] (Bar-Shalom, Li & Kirubarajan 2001, sec. 6.2.2).
    """
    Q = np.zeros((4, 4))
    a, b, c = q * dt**3 / 3.0, q * dt**2 / 2.0, q * dt
    Q[0, 0] = Q[1, 1] = a
    Q[0, 2] = Q[2, 0] = Q[1, 3] = Q[3, 1] = b
    Q[2, 2] = Q[3, 3] = c
    return Q


def _as_time(t: float) -> float:
    try:
        value = float(t)
    except (TypeError, ValueError):
        raise InvalidInput(f"t must be a time in seconds, got {t!r}") from None
    if not math.isfinite(value):
        raise InvalidInput(f"t must be a finite time in seconds, got {t}")
    return value


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


def _as_labels(labels: Sequence[str | None] | None, n: int) -> NDArray[np.object_]:
    out = np.empty(n, dtype=object)
    if labels is None:
        return out
    if isinstance(labels, str) or len(labels) != n:
        raise InvalidInput(f"labels must be a sequence of {n} strings or None, one per measurement")
    for i, lab in enumerate(labels):
        if lab is not None and not isinstance(lab, str):
            raise InvalidInput(f"labels must be strings or None, got {type(lab).__name__}")
        out[i] = lab
    return out


def _mahalanobis(nu: Array, S: Array) -> tuple[Array, Array]:
    """Return (nu^T S^-1 nu, ln det S), both (...), for nu (..., 2) and S (..., 2, 2)."""
    S_inv, det = inv2(S)
    d2 = np.einsum("...i,...ij,...j->...", nu, S_inv, nu)
    with np.errstate(divide="ignore", invalid="ignore"):
        return d2, np.log(det)


def _assign(cost: Array, allowed: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Return the (rows, cols) of the minimum-cost assignment using allowed pairs only."""
    rows_any = np.flatnonzero(allowed.any(axis=1))
    cols_any = np.flatnonzero(allowed.any(axis=0))
    if rows_any.size == 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty
    sub_ok = allowed[np.ix_(rows_any, cols_any)]
    sub = np.where(sub_ok, np.clip(cost[np.ix_(rows_any, cols_any)], -_MAX_COST, _MAX_COST), 0.0)
    sub = np.where(sub_ok, sub, _FORBIDDEN)
    r, c = linear_sum_assignment(sub)
    keep = sub_ok[r, c]
    return rows_any[r[keep]], cols_any[c[keep]]


class FloorTracker:
    """Tracks many targets on the floor plane from floor positions or per-camera detections.

    cameras: the calibrated network, needed only by `update_detections`. config: a
    `TrackerConfig`. Time is in seconds and must not decrease from one call to the next.
    Track ids are positive integers, never reused.
    """

    def __init__(
        self,
        config: TrackerConfig | None = None,
        cameras: Sequence[NetworkCamera] | None = None,
    ) -> None:
        self.config = TrackerConfig() if config is None else config
        if not isinstance(self.config, TrackerConfig):
            raise InvalidInput(f"config must be a TrackerConfig, got {type(config).__name__}")
        self.cameras: tuple[NetworkCamera, ...] = () if cameras is None else as_cameras(cameras)
        self._t: float | None = None
        self._x = np.zeros((0, 4))
        self._P = np.zeros((0, 4, 4))
        self._ids: list[int] = []
        self._labels: list[str | None] = []
        self._confirmed: list[bool] = []
        self._frames: list[int] = []  # frames seen since birth, birth included
        self._hits: list[int] = []
        self._last: list[float] = []
        self._history: list[deque[TrackPoint]] = []
        self._next_id = 1

    # -- state ---------------------------------------------------------------------------------

    @property
    def time(self) -> float | None:
        """Time of the last frame (s), None before the first."""
        return self._t

    def __len__(self) -> int:
        return len(self._ids)

    def tracks(
        self, t: float | None = None, *, confirmed_only: bool = False
    ) -> tuple[TrackSnapshot, ...]:
        """Return snapshots of the tracks, predicted to time t (s) if given (not stored)."""
        x, P = self._x, self._P
        when = self._t
        if t is not None:
            t = _as_time(t)
            x, P = self._predicted(t)
            when = t
        out = []
        for i, tid in enumerate(self._ids):
            if confirmed_only and not self._confirmed[i]:
                continue
            out.append(
                TrackSnapshot(
                    id=tid,
                    label=self._labels[i],
                    status=TrackStatus.CONFIRMED if self._confirmed[i] else TrackStatus.TENTATIVE,
                    t=float("nan") if when is None else when,
                    state=x[i].copy(),
                    cov=P[i].copy(),
                    hits=self._hits[i],
                    last_update=self._last[i],
                    history=tuple(self._history[i]),
                )
            )
        return tuple(out)

    def _predicted(self, t: float) -> tuple[Array, Array]:
        """Return every track's state (T, 4) and covariance (T, 4, 4) predicted to time t."""
        if self._t is None:
            return self._x, self._P
        dt = t - self._t
        if dt < 0:
            raise InvalidInput(
                f"time went backwards: t = {t} s is before the last frame at {self._t} s; "
                "feed frames in time order"
            )
        if dt == 0 or not self._ids:
            return self._x, self._P
        F = cv_transition(dt)
        x = self._x @ F.T
        P = F @ self._P @ F.T + cv_process_noise(dt, self.config.q)
        return x, P

    def predict(self, t: float) -> None:
        """Advance every track to time t (s): s <- F s, P <- F P F^T + Q (vectorised)."""
        t = _as_time(t)
        self._x, self._P = self._predicted(t)
        self._t = t

    # -- floor measurements --------------------------------------------------------------------

    def update(
        self,
        t: float,
        xy: ArrayLike,
        cov: ArrayLike,
        labels: Sequence[str | None] | None = None,
    ) -> FrameAssociation:
        """Return what the frame at time t did after updating the tracks with floor measurements.

        xy: (M, 2) positions on the floor, metres; cov: (M, 2, 2) or one (2, 2) for all, m^2
        (e.g. `FloorEstimate.xy` and `.cov` of the valid targets); labels: M strings or None.
        Predicts to t, associates by GNN with Mahalanobis gating, updates, starts, confirms and
        deletes tracks. M = 0 is a frame without detections.
        """
        t = _as_time(t)
        try:
            z = np.array(xy, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInput(f"xy must be numeric, shape (M, 2): {exc}") from None
        if z.size == 0:
            z = z.reshape(0, 2)
        if z.ndim != 2 or z.shape[1] != 2:
            raise InvalidInput(f"xy must have shape (M, 2), got {z.shape}")
        if not np.all(np.isfinite(z)):
            raise InvalidInput("xy contains NaN or infinite values; drop invalid estimates first")
        R = _as_covariances(cov, z.shape[0], "cov")
        labs = _as_labels(labels, z.shape[0])
        self.predict(t)
        n_old = len(self._ids)
        rows, cols = self._associate_floor(z, R, labs)
        track_ids = np.full(z.shape[0], -1, dtype=np.int64)
        ids = np.array(self._ids, dtype=np.int64)
        track_ids[cols] = ids[rows]
        self._kalman_update(rows, z[cols], R[cols])
        hit = np.zeros(n_old, dtype=bool)
        hit[rows] = True
        unassigned = np.setdiff1d(np.arange(z.shape[0]), cols)
        started = np.zeros(z.shape[0], dtype=bool)
        new_ids = self._start(z[unassigned], R[unassigned], labs[unassigned])
        track_ids[unassigned] = new_ids
        started[unassigned] = new_ids >= 0
        deleted = self._manage(hit)
        return FrameAssociation(t, track_ids, started, deleted)

    def _compatible(self, labs: NDArray[np.object_]) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
        """Return (may pair (T, M): same label, or none on the measurement; labelled (M,))."""
        track_labs = np.empty(len(self._labels), dtype=object)
        track_labs[:] = self._labels
        labelled = np.array([lab is not None for lab in labs], dtype=bool)
        match = (track_labs[:, None] == labs[None, :]) | ~labelled[None, :]
        return match, labelled

    def _associate_floor(
        self, z: Array, R: Array, labs: NDArray[np.object_]
    ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Return the GNN pairs (track rows, measurement indices) of floor measurements."""
        if not self._ids or z.shape[0] == 0:
            empty = np.zeros(0, dtype=np.intp)
            return empty, empty
        nu = z[None, :, :] - self._x[:, None, :2]  # (T, M, 2)
        S = self._P[:, None, :2, :2] + R[None]  # (T, M, 2, 2)
        d2, logdet = _mahalanobis(nu, S)
        match, labelled = self._compatible(labs)
        allowed = match & ((d2 <= self.config.gate) | labelled[None, :]) & np.isfinite(d2)
        return self._assign_in_rounds(d2 + logdet, allowed, labelled)

    def _assign_in_rounds(
        self, cost: Array, allowed: NDArray[np.bool_], labelled: NDArray[np.bool_]
    ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Return GNN pairs (track rows, columns) of cost (T, M): labelled measurements first,
        then unlabelled ones to confirmed tracks, then to tentative ones."""
        confirmed = np.array(self._confirmed, dtype=bool)
        rows: list[NDArray[np.intp]] = []
        cols: list[NDArray[np.intp]] = []
        free = allowed.copy()
        for mask in (
            labelled[None, :],
            ~labelled[None, :] & confirmed[:, None],
            ~labelled[None, :] & ~confirmed[:, None],
        ):
            r, c = _assign(cost, free & mask)
            free[r, :] = False
            free[:, c] = False
            rows.append(r)
            cols.append(c)
        return np.concatenate(rows), np.concatenate(cols)

    def _kalman_update(self, rows: NDArray[np.intp], z: Array, R: Array) -> None:
        """Update tracks `rows` with measurements z (n, 2), R (n, 2, 2); Joseph form."""
        if rows.size == 0:
            return
        x = self._x[rows]
        P = self._P[rows]
        S = P[:, :2, :2] + R
        S_inv = inv2(S)[0]
        K = P[:, :, :2] @ S_inv  # (n, 4, 2)
        nu = z - x[:, :2]
        x = x + (K @ nu[:, :, None])[:, :, 0]
        A = np.broadcast_to(np.eye(4), P.shape).copy()
        A[:, :, :2] -= K  # I - K H with H = [I 0]
        P = A @ P @ transposed(A) + K @ R @ transposed(K)
        P = 0.5 * (P + transposed(P))
        self._x[rows] = x
        self._P[rows] = P
        t = float(self._t) if self._t is not None else 0.0
        for j, i in enumerate(rows.tolist()):
            self._hits[i] += 1
            self._last[i] = t
            self._history[i].append(TrackPoint(t, x[j, :2].copy(), P[j, :2, :2].copy()))

    def _start(self, z: Array, R: Array, labs: NDArray[np.object_]) -> NDArray[np.int64]:
        """Start tracks at unassigned measurements; return their ids (-1: not started).

        The most precise measurements go first, and each is checked against every track,
        those it just started included: an unlabelled measurement within `birth_gate` of any
        track is an outlier of that target, not a new one; a label starts at most one track.
        """
        ids = np.full(z.shape[0], -1, dtype=np.int64)
        order = np.argsort(R[:, 0, 0] * R[:, 1, 1] - R[:, 0, 1] * R[:, 1, 0], kind="stable")
        for j in order.tolist():
            lab = labs[j]
            if lab is not None:
                if lab in self._labels:
                    continue
            elif self._ids:
                d2, _ = _mahalanobis(z[j] - self._x[:, :2], self._P[:, :2, :2] + R[j])
                if np.any(d2 <= self.config.birth_gate):
                    continue
            ids[j] = self._birth(z[j], R[j], lab)
        return ids

    def _birth(self, z: Array, R: Array, label: str | None) -> int:
        x = np.array([z[0], z[1], 0.0, 0.0])
        P = np.zeros((4, 4))
        P[:2, :2] = R
        P[2, 2] = P[3, 3] = self.config.initial_speed_std**2
        tid = self._next_id
        self._next_id += 1
        t = float(self._t) if self._t is not None else 0.0
        self._x = np.concatenate([self._x, x[None]])
        self._P = np.concatenate([self._P, P[None]])
        self._ids.append(tid)
        self._labels.append(label)
        self._confirmed.append(self.config.confirm_hits <= 1)
        self._frames.append(0)
        self._hits.append(1)
        self._last.append(t)
        hist: deque[TrackPoint] = deque(maxlen=self.config.history_length)
        hist.append(TrackPoint(t, z.copy(), R.copy()))
        self._history.append(hist)
        return tid

    def _manage(self, hit: NDArray[np.bool_]) -> tuple[int, ...]:
        """Count the frame for the tracks that existed before it (`hit` says which were updated),
        confirm after M of N, delete the tracks that missed too long or failed confirmation."""
        cfg = self.config
        t = float(self._t) if self._t is not None else 0.0
        keep = np.ones(len(self._ids), dtype=bool)
        for i in range(len(hit)):
            self._frames[i] += 1
            if not self._confirmed[i]:
                if self._hits[i] >= cfg.confirm_hits:
                    self._confirmed[i] = True
                elif self._frames[i] >= cfg.confirm_window:
                    keep[i] = False
            if t - self._last[i] > cfg.max_miss_time:
                keep[i] = False
        for i in range(len(hit), len(self._ids)):
            self._frames[i] = 1
        if keep.all():
            return ()
        deleted = tuple(tid for tid, k in zip(self._ids, keep, strict=True) if not k)
        idx = np.flatnonzero(keep)
        self._x = self._x[idx]
        self._P = self._P[idx]
        for name in ("_ids", "_labels", "_confirmed", "_frames", "_hits", "_last", "_history"):
            old = getattr(self, name)
            setattr(self, name, [old[i] for i in idx.tolist()])
        return deleted

    # -- per-camera detections -----------------------------------------------------------------

    def update_detections(
        self,
        t: float,
        camera_index: ArrayLike,
        pixels: ArrayLike,
        pixel_cov: ArrayLike | None = None,
        *,
        pixel_sigma: float = 1.0,
        labels: Sequence[str | None] | None = None,
    ) -> FrameAssociation:
        """Return what the frame did after updating the tracks with raw per-camera detections.

        camera_index: (D,) integers into `cameras`; pixels: (D, 2) distorted pixels; pixel_cov:
        (D, 2, 2) or (2, 2) px^2, or None for sigma^2 I with sigma = pixel_sigma (px); labels: D
        strings or None. A camera sees each target at most once.

        1. Predict the tracks to t. 2. For each camera k, project each predicted position onto
        the image, u_i = pi_k(x_i, y_i, h), with S_ik = J P_xy J^T + Sigma_pixel (J = d pi_k /
        d(x, y)); GNN-assign camera k's detections to the tracks under the gate on
        (u - u_i)^T S_ik^-1 (u - u_i). 3. Each track's detections (one per camera) are fused
        by `locate_ml` (all tracks in one batched call) into a floor measurement with its
        inverse-Fisher covariance, which updates the track unless it lies beyond `birth_gate`
        from the prediction (then the group mixed targets and its detections are dropped).
        4. Detections no track took are back-projected onto Z = h (`locate_monocular`, with
        covariance C); detections a, b of different cameras are consistent when
        (p_a - p_b)^T (C_a + C_b)^-1 (p_a - p_b) is within the gate; consistent groups (one
        detection per camera, pairwise consistent, built greedily from the closest pairs) are
        fused by `locate_ml` and start tracks.
        """
        if not self.cameras:
            raise InvalidInput(
                "update_detections needs the camera network: construct FloorTracker(cameras=...)"
            )
        t = _as_time(t)
        cam, px, pcov, labs = self._parse_detections(
            camera_index, pixels, pixel_cov, pixel_sigma, labels
        )
        self.predict(t)
        n_det = cam.size
        n_old = len(self._ids)
        track_ids = np.full(n_det, -1, dtype=np.int64)
        started = np.zeros(n_det, dtype=bool)
        owner = self._associate_pixels(cam, px, pcov, labs)  # (D,) track row or -1
        hit = np.zeros(n_old, dtype=bool)
        rows = np.unique(owner[owner >= 0])
        if rows.size:
            est = self._fuse(rows, owner, cam, px, pcov)
            ok = est.valid
            # Each camera passed its gate, but the group could still mix two targets: refuse
            # a fused point that is implausible (beyond birth_gate) for its track.
            d2, _ = _mahalanobis(
                np.where(ok[:, None], est.xy, 0.0) - self._x[rows, :2],
                self._P[rows, :2, :2] + np.where(ok[:, None, None], est.cov, np.eye(2)),
            )
            row_labelled = np.array([self._labels[i] is not None for i in rows], dtype=bool)
            ok &= row_labelled | (d2 <= self.config.birth_gate)
            z, R = est.xy[ok], est.cov[ok]
            good = rows[ok]
            self._kalman_update(good, z, R)
            hit[good] = True
            ids = np.array(self._ids, dtype=np.int64)
            fused = np.isin(owner, good)
            track_ids[fused] = ids[owner[fused]]
        free = np.flatnonzero(owner < 0)
        if free.size:
            groups = self._group(free, cam, px, pcov, labs)
            if groups:
                self._start_groups(groups, cam, px, pcov, labs, track_ids, started)
        deleted = self._manage(hit)
        return FrameAssociation(t, track_ids, started, deleted)

    def _parse_detections(
        self,
        camera_index: ArrayLike,
        pixels: ArrayLike,
        pixel_cov: ArrayLike | None,
        pixel_sigma: float,
        labels: Sequence[str | None] | None,
    ) -> tuple[NDArray[np.intp], Array, Array, NDArray[np.object_]]:
        cam_raw = np.asarray(camera_index)
        if cam_raw.size == 0:
            cam_raw = cam_raw.reshape(0).astype(np.intp)
        if cam_raw.ndim != 1 or not np.issubdtype(cam_raw.dtype, np.integer):
            raise InvalidInput(
                f"camera_index must be a 1-D integer array (D,), got dtype {cam_raw.dtype} "
                f"shape {cam_raw.shape}"
            )
        cam = cam_raw.astype(np.intp)
        n = cam.size
        if np.any(cam < 0) or np.any(cam >= len(self.cameras)):
            raise InvalidInput(
                f"camera_index must lie in [0, {len(self.cameras)}) (the tracker's cameras)"
            )
        try:
            px = np.array(pixels, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInput(f"pixels must be numeric, shape (D, 2): {exc}") from None
        if px.size == 0:
            px = px.reshape(0, 2)
        if px.shape != (n, 2):
            raise InvalidInput(f"pixels must have shape ({n}, 2), got {px.shape}")
        if not np.all(np.isfinite(px)):
            raise InvalidInput("pixels contain NaN or infinite values")
        if pixel_cov is None:
            sigma = float(pixel_sigma)
            if not math.isfinite(sigma) or sigma <= 0:
                raise InvalidInput(f"pixel_sigma must be a positive number of pixels, got {sigma}")
            pcov = np.broadcast_to(np.eye(2) * sigma**2, (n, 2, 2)).copy()
        else:
            pcov = _as_covariances(pixel_cov, n, "pixel_cov")
        labs = _as_labels(labels, n)
        named = [(int(k), lab) for k, lab in zip(cam, labs, strict=True) if lab is not None]
        if len(named) != len(set(named)):
            raise InvalidInput("a camera reports the same label twice in one frame")
        return cam, px, pcov, labs

    def _associate_pixels(
        self, cam: NDArray[np.intp], px: Array, pcov: Array, labs: NDArray[np.object_]
    ) -> NDArray[np.intp]:
        """Return the track row each detection was assigned to (-1: none), camera by camera."""
        owner = np.full(cam.size, -1, dtype=np.intp)
        if not self._ids or cam.size == 0:
            return owner
        h = self.config.height
        xy = self._x[:, :2]
        Pxy = self._P[:, :2, :2]
        match, labelled = self._compatible(labs)
        for k, camera in enumerate(self.cameras):
            det = np.flatnonzero(cam == k)
            if det.size == 0:
                continue
            proj = project_plane(camera, xy, h, jacobian=True)
            J = proj.jacobian
            assert J is not None
            front = proj.depth > 0
            S = (J @ Pxy @ transposed(J))[:, None] + pcov[det][None]  # (T, n, 2, 2)
            nu = px[det][None, :, :] - proj.pixels[:, None, :]
            d2, logdet = _mahalanobis(nu, S)
            gated = (d2 <= self.config.gate) | labelled[det][None, :]
            allowed = match[:, det] & gated & front[:, None] & np.isfinite(d2)
            rows, cols = self._assign_in_rounds(d2 + logdet, allowed, labelled[det])
            owner[det[cols]] = rows
        return owner

    def _fuse(
        self,
        rows: NDArray[np.intp],
        owner: NDArray[np.intp],
        cam: NDArray[np.intp],
        px: Array,
        pcov: Array,
    ) -> FloorEstimate:
        """Return the ML floor estimate of each track row's detection group (one batched call)."""
        slot = np.searchsorted(rows, owner)
        sel = np.flatnonzero(owner >= 0)
        return self._locate(rows.size, slot[sel], cam[sel], px[sel], pcov[sel])

    def _locate(
        self, n_groups: int, group: NDArray[np.intp], cam: NDArray[np.intp], px: Array, pcov: Array
    ) -> FloorEstimate:
        """Return the ML estimates of n_groups targets; detection i belongs to group[i]."""
        n_cam = len(self.cameras)
        pixels = np.zeros((n_cam, n_groups, 2))
        cov = np.broadcast_to(np.eye(2), (n_cam, n_groups, 2, 2)).copy()
        visible = np.zeros((n_cam, n_groups), dtype=bool)
        pixels[cam, group] = px
        cov[cam, group] = pcov
        visible[cam, group] = True
        return locate_ml(self.cameras, pixels, self.config.height, visible=visible, pixel_cov=cov)

    def _group(
        self,
        free: NDArray[np.intp],
        cam: NDArray[np.intp],
        px: Array,
        pcov: Array,
        labs: NDArray[np.object_],
    ) -> list[list[int]]:
        """Return groups of the free detections that are one target seen by different cameras.

        Each free detection is back-projected onto Z = h with its covariance; pairs of different
        cameras and the same label whose points agree within the gate are merged, closest pair
        first, as long as a group holds one detection per camera and stays pairwise consistent.
        Detections whose ray misses the plane are left out.
        """
        h = self.config.height
        xy = np.full((free.size, 2), np.nan)
        C = np.broadcast_to(np.eye(2), (free.size, 2, 2)).copy()
        ok = np.zeros(free.size, dtype=bool)
        for k, camera in enumerate(self.cameras):
            sel = np.flatnonzero(cam[free] == k)
            if sel.size == 0:
                continue
            est = locate_monocular(camera, px[free[sel]], h, pixel_cov=pcov[free[sel]])
            v = est.valid
            xy[sel[v]] = est.xy[v]
            C[sel[v]] = est.cov[v]
            ok[sel[v]] = True
        idx = np.flatnonzero(ok)
        det = free[idx]
        p, Cv = xy[idx], C[idx]
        n = det.size
        if n == 0:
            return []
        d2, _ = _mahalanobis(p[:, None] - p[None, :], Cv[:, None] + Cv[None, :])
        c = cam[det]
        lab = labs[det]
        consistent = (c[:, None] != c[None, :]) & (lab[:, None] == lab[None, :])
        consistent &= d2 <= self.config.gate
        members: list[list[int]] = [[i] for i in range(n)]
        group_of = list(range(n))
        a, b = np.nonzero(np.triu(consistent, 1))
        for i, j in zip(*(x[np.argsort(d2[a, b], kind="stable")] for x in (a, b)), strict=True):
            gi, gj = group_of[i], group_of[j]
            if gi == gj:
                continue
            A, B = members[gi], members[gj]
            if not consistent[np.ix_(A, B)].all():
                continue  # also catches two detections of one camera
            members[gi] = A + B
            members[gj] = []
            for m in B:
                group_of[m] = gi
        return [[int(det[m]) for m in g] for g in members if g]

    def _start_groups(
        self,
        groups: list[list[int]],
        cam: NDArray[np.intp],
        px: Array,
        pcov: Array,
        labs: NDArray[np.object_],
        track_ids: NDArray[np.int64],
        started: NDArray[np.bool_],
    ) -> None:
        """Locate each group by ML and start its track; fill track_ids and started in place."""
        members = np.concatenate([np.asarray(g, dtype=np.intp) for g in groups])
        group = np.repeat(np.arange(len(groups)), [len(g) for g in groups])
        est = self._locate(len(groups), group, cam[members], px[members], pcov[members])
        ok = np.flatnonzero(est.valid)
        if ok.size == 0:
            return
        group_labs = np.empty(len(groups), dtype=object)
        group_labs[:] = [labs[g[0]] for g in groups]
        ids = self._start(est.xy[ok], est.cov[ok], group_labs[ok])
        for gi, tid in zip(ok.tolist(), ids.tolist(), strict=True):
            if tid >= 0:
                track_ids[groups[gi]] = tid
                started[groups[gi]] = True
