"""Tracking scenarios of the digital twin and their scoring by the standard MOT metrics.

* `tracking` (the service's own pipeline, on pixels): the home with the robot patrolling and
  three walkers (paths that cross, pauses), every ceiling camera rendering at `RENDER_RATE_HZ`
  with its own phase; in each image the robot's marker and the people are detected
  (core.localization.detections.detect_frame, what the twin's loop and a camera node call) and
  the detections go, camera frame by camera frame, to the one tracker, which knows the cameras
  and the floor plan (walls, furniture), never the truth. Scored against the walkers' centres
  and the robot's centre.
* `tracking-async` (spec 08's acceptance): the home's first four ceiling cameras report at 10 Hz,
  each with its own phase, the points of three walkers at 1.0 m above the floor (projected, not
  rendered) with 0.7 px noise, 5 % missed detections and clutter (false detections uniform over
  the image); the walkers' paths cross and they stand still 2-10 s at some waypoints. Every
  frame goes, unlabelled and in time order, to the one tracker (core.localization.tracking).

The score (`score_tracks`) uses py-motmetrics (the CLEAR MOT metrics of Bernardin &
Stiefelhagen 2008 and IDF1 of Ristani et al. 2016) at 10 Hz truth instants with a 0.5 m match
distance, each track answering with its point nearest in time (within 0.06 s): MOTA, IDF1,
identity switches, the most live (confirmed or coasting) tracks at any instant, and the RMSE of
matched positions.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.localization import NetworkCamera, Occluders, line_of_sight
from core.localization.detect import MarkerDetectorConfig, PersonDetector
from core.localization.detections import FrameDetection, detect_frame
from core.localization.tracking import FrameResult, Tracker, TrackerConfig, TrackState
from core.sim.crowd import Crowd, crowd_of
from core.sim.motion import Pose2D, WorldState, simulate_patrol
from core.sim.occluders import scene_occluders
from core.sim.render import ExposureChanges, Renderer, camera_model, renderer_for
from core.sim.scene import Robot, Scene, Walker, default_scene

Array = NDArray[np.float64]

# Spec 08's conditions.
ASYNC_RATE_HZ = 10.0
ASYNC_NOISE_PX = 0.7
ASYNC_MISS = 0.05
# False detections per camera frame (Poisson mean), uniform over the image.
ASYNC_CLUTTER = 0.3
ASYNC_HEIGHT_M = 1.0
# Spec 08's acceptance names four cameras: the home's first four, one per room corner that
# looks over each room (the default home's fifth, a second view of the kitchen, is left out).
ASYNC_CAMERAS = 4
# Scoring: truth instants per second, match distance (m), a track point's time tolerance (s).
SCORE_HZ = 10.0
MATCH_DISTANCE_M = 0.5
POINT_TOLERANCE_S = 0.06

# Two more people of the home for the tracking scenarios: the resident walks a round that
# crosses the first walker's path twice and the robot's patrol, the visitor walks between the
# bedroom and the kitchen, and both stand still at waypoints. People give way to each other and
# to the robot (core.sim.crowd), so nobody stands or turns round where another walks or the
# robot drives: they could not get out of the way there.
EXTRA_WALKERS = (
    Walker(
        name="resident",
        waypoints=[(3.4, 4.8), (2.5, 3.6), (2.5, 1.65), (2.9, 1.65), (2.9, 3.6)],
        speed=0.9,
        loop=True,
        pauses=[7.0, 0.0, 0.0, 0.0, 0.0],
        colour=(40, 90, 160),
    ),
    Walker(
        name="visitor",
        waypoints=[(5.6, 4.4), (6.55, 3.4), (6.55, 2.6), (5.3, 2.5)],
        speed=0.7,
        pauses=[5.0, 0.0, 0.0, 4.0],
        colour=(150, 130, 40),
    ),
)


def tracking_scene(scene: Scene | None = None) -> Scene:
    """Return `scene` (the default home when None) with the scenario's walkers added: the
    first walker gets pauses of 2 and 6 s at two waypoints when it has none."""
    scene = default_scene() if scene is None else scene
    names = {p.name for p in scene.people}
    people = []
    for p in scene.people:
        if not p.pauses and len(p.waypoints) >= 3:
            pauses = [0.0] * len(p.waypoints)
            pauses[1], pauses[-1] = 2.0, 6.0
            p = p.model_copy(update={"pauses": pauses})
        people.append(p)
    people += [w for w in EXTRA_WALKERS if w.name not in names]
    return scene.model_copy(update={"people": people})


# --------------------------------------------------------------------------------------------
# Recording what the tracker reports, and scoring it


@dataclass
class TrackLog:
    """Collects a tracker's reports: each track's points while it is confirmed (t, x, y, vx,
    vy), the time it was first confirmed and the time it ended."""

    points: dict[int, list[tuple[float, ...]]] = field(default_factory=dict)
    confirmed_at: dict[int, float] = field(default_factory=dict)
    ended_at: dict[int, float] = field(default_factory=dict)

    def add(self, result: FrameResult) -> None:
        """Record one frame's updates and ended tracks."""
        for snap in result.updated:
            if snap.state is TrackState.CONFIRMED:
                self.confirmed_at.setdefault(snap.id, snap.t)
                self.points.setdefault(snap.id, []).append((snap.t, *(float(v) for v in snap.x)))
        for snap in result.ended:
            self.ended_at[snap.id] = result.t

    def end(self, ended: Iterable[Any], t: float) -> None:
        """Record tracks that ended at time t without a frame (Tracker.advance)."""
        for snap in ended:
            self.ended_at[snap.id] = t


def frame_alignment(calibrated: list[NetworkCamera], truth: list[NetworkCamera]) -> Array:
    """Return the 3x3 planar rigid transform (rotation about the vertical, then translation)
    taking the calibrated home frame to the twin's, fitted by least squares to the cameras'
    centres (Kabsch in the plane). The calibration fixes its frame by the robot's start pose
    and its first straight leg, so that frame carries a small rigid error of its own (the
    calibration's gauge, inside its Cramer-Rao bound); scoring with and without this transform
    separates the tracker's error from the frame's. For scoring only: it reads the truth."""
    a = np.array([c.center[:2] for c in calibrated])
    b = np.array([c.center[:2] for c in truth])
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    r = (u @ vt).T
    if np.linalg.det(r) < 0:
        vt[-1] *= -1
        r = (u @ vt).T
    T = np.eye(3)
    T[:2, :2] = r
    T[:2, 2] = cb - r @ ca
    return T


def frame_error(calibrated: list[NetworkCamera], T: Array) -> tuple[float, float]:
    """Return the calibrated frame's error: the largest displacement (m) T makes at a
    calibrated camera's centre, and its rotation (deg)."""
    a = np.array([c.center[:2] for c in calibrated])
    moved = a @ T[:2, :2].T + T[:2, 2]
    shift = float(np.max(np.linalg.norm(moved - a, axis=1)))
    return shift, float(np.degrees(abs(np.arctan2(T[1, 0], T[0, 0]))))


def transformed(log: TrackLog, T: Array) -> TrackLog:
    """Return `log` with its points (t, x, y[, vx, vy]) moved by the planar transform T."""
    R, t = T[:2, :2], T[:2, 2]
    points: dict[int, list[tuple[float, ...]]] = {}
    for k, pts in log.points.items():
        arr = np.asarray(pts, dtype=np.float64).reshape(len(pts), -1)
        out = arr.copy()
        out[:, 1:3] = arr[:, 1:3] @ R.T + t
        if arr.shape[1] >= 5:
            out[:, 3:5] = arr[:, 3:5] @ R.T
        points[k] = [tuple(row) for row in out.tolist()]
    return TrackLog(points, dict(log.confirmed_at), dict(log.ended_at))


@dataclass(frozen=True)
class TrackingScore:
    """The MOT metrics of a run: MOTA, IDF1, identity switches, false positives, misses,
    matches, the most live tracks at one instant, and the RMSE (m) of matched positions (all,
    and of the bodies `score_tracks` was asked about)."""

    mota: float
    idf1: float
    id_switches: int
    false_positives: int
    misses: int
    matches: int
    max_live_targets: int
    rmse_m: float
    class_rmse_m: float


def score_tracks(
    truth_t: Array,
    truth_xy: Array,
    log: TrackLog,
    *,
    match_distance: float = MATCH_DISTANCE_M,
    classes: NDArray[np.int64] | None = None,
    truth_at: Callable[[Array], Array] | None = None,
    predict_within: float | None = None,
    rmse_where: NDArray[np.bool_] | None = None,
) -> TrackingScore:
    """Return the MOT metrics of the tracks in `log` against the truth.

    truth_t: (N,) instants (s); truth_xy: (N, B, 2) the B bodies' floor positions (m), NaN
    where a body is not to be tracked. At each instant every live track (confirmed at or
    before it, not ended) answers with its point nearest in time within `POINT_TOLERANCE_S`;
    matching uses squared Euclidean distances gated at match_distance (motmetrics).
    `class_rmse_m` is the RMSE over the matches of the bodies in `classes` (all when None).
    With `truth_at` (times (N,) -> positions (N, B, 2)) the RMSE compares each matched point
    with the truth at the point's own time rather than at the instant it answers for. With
    `predict_within` (s) a track answers instead with its latest point at most that old,
    moved on by its velocity to the instant (what a live display shows between updates of
    cameras slower than the scoring rate); its points must then carry (t, x, y, vx, vy).
    `rmse_where` (N, B) limits the class RMSE to those (instant, body) pairs.
    """
    import motmetrics as mm  # a scoring dependency, loaded only when scoring

    acc = mm.MOTAccumulator(auto_id=True)
    series = {tid: np.asarray(pts, dtype=np.float64) for tid, pts in log.points.items() if len(pts)}
    ids = np.array(sorted(series), dtype=np.int64)
    start = np.array([log.confirmed_at.get(int(i), np.inf) for i in ids])
    stop = np.array([log.ended_at.get(int(i), np.inf) for i in ids])
    max_live = 0
    answered: list[dict[int, Array]] = []  # per instant: track id -> its point (t, x, y)
    point_of: dict[int, Array] = {}
    for k, tau in enumerate(truth_t):
        live = ids[(start <= tau) & (tau < stop)]
        max_live = max(max_live, int(live.size))
        hyp_ids, hyp_xy = [], []
        for tid in live.tolist():
            pts = series[tid]
            if predict_within is not None:
                j = int(np.searchsorted(pts[:, 0], tau, side="right")) - 1
                if j >= 0 and tau - pts[j, 0] <= predict_within:
                    xy = pts[j, 1:3] + pts[j, 3:5] * (tau - pts[j, 0])
                    hyp_ids.append(tid)
                    hyp_xy.append(xy)
                    point_of[tid] = pts[j, :3]  # the RMSE takes the update at its own time
                continue
            j = int(np.searchsorted(pts[:, 0], tau))
            best = None
            for c in (j - 1, j):
                if 0 <= c < len(pts) and abs(pts[c, 0] - tau) <= POINT_TOLERANCE_S:
                    if best is None or abs(pts[c, 0] - tau) < abs(pts[best, 0] - tau):
                        best = c
            if best is not None:
                hyp_ids.append(tid)
                hyp_xy.append(pts[best, 1:3])
                point_of[tid] = pts[best, :3]
        answered.append(dict(point_of))
        point_of.clear()
        present = np.flatnonzero(np.all(np.isfinite(truth_xy[k]), axis=1))
        gt = truth_xy[k, present]
        hyp = np.asarray(hyp_xy, dtype=np.float64).reshape(-1, 2)
        dist = mm.distances.norm2squared_matrix(gt, hyp, max_d2=match_distance**2)
        acc.update(present.tolist(), hyp_ids, dist)
    mh = mm.metrics.create()
    summary = mh.compute(
        acc,
        metrics=[
            "mota",
            "idf1",
            "num_switches",
            "num_false_positives",
            "num_misses",
            "num_matches",
        ],
        name="run",
    )
    row = summary.loc["run"]
    events = acc.mot_events
    matched = events[events["Type"] == "MATCH"]
    d2 = matched["D"].to_numpy(dtype=np.float64)
    if truth_at is not None and len(matched):
        frame = matched.index.get_level_values(0).to_numpy()
        oid = matched["OId"].to_numpy(dtype=np.int64)
        hid = matched["HId"].to_numpy(dtype=np.int64)
        pts = np.array([answered[f][h] for f, h in zip(frame, hid, strict=True)])
        true = truth_at(pts[:, 0])[np.arange(len(pts)), oid]
        d2 = np.sum((pts[:, 1:] - true) ** 2, axis=1)
    rmse = float(np.sqrt(np.mean(d2))) if d2.size else float("nan")
    mine = np.ones(len(matched), dtype=bool)
    if classes is not None:
        mine &= matched["OId"].isin([int(c) for c in classes]).to_numpy()
    if rmse_where is not None and len(matched):
        frame = matched.index.get_level_values(0).to_numpy()
        mine &= rmse_where[frame, matched["OId"].to_numpy(dtype=np.int64)]
    d2c = d2[mine]
    class_rmse = float(np.sqrt(np.mean(d2c))) if d2c.size else float("nan")
    return TrackingScore(
        mota=float(row["mota"]),
        idf1=float(row["idf1"]),
        id_switches=int(row["num_switches"]),
        false_positives=int(row["num_false_positives"]),
        misses=int(row["num_misses"]),
        matches=int(row["num_matches"]),
        max_live_targets=max_live,
        rmse_m=rmse,
        class_rmse_m=class_rmse,
    )


# --------------------------------------------------------------------------------------------
# tracking-async: projected points from unsynchronised cameras


@dataclass(frozen=True)
class CameraFrameDetections:
    """One camera frame: its capture time (s), the camera's index, the detections' pixels
    (D, 2), and which body each came from (-1 for clutter; for scoring only)."""

    t: float
    camera: int
    pixels: Array
    source: NDArray[np.int64]


def async_camera_frames(
    scene: Scene,
    cameras: list[NetworkCamera],
    duration_s: float,
    rng: np.random.Generator,
    *,
    rate_hz: float = ASYNC_RATE_HZ,
    noise_px: float = ASYNC_NOISE_PX,
    miss: float = ASYNC_MISS,
    clutter: float = ASYNC_CLUTTER,
    height: float = ASYNC_HEIGHT_M,
) -> list[CameraFrameDetections]:
    """Return every camera's frames over `duration_s`, in capture-time order: each camera at
    `rate_hz` with its own random phase and a small jitter, each walker's point at `height`
    projected into the cameras that see it (in front, inside the image), Gaussian pixel noise,
    a detection missed with probability `miss`, and Poisson(`clutter`) false detections."""
    period = 1.0 / rate_hz
    frames: list[CameraFrameDetections] = []
    for k, cam in enumerate(cameras):
        phase = rng.uniform(0.0, period)
        n = int(np.floor((duration_s - phase) / period)) + 1
        times = phase + period * np.arange(n) + rng.normal(0.0, 0.002, n)
        times = np.clip(times, 0.0, duration_s)
        P = _walkers_at(scene, times)  # (n, B, 2)
        B = P.shape[1]
        pts = np.concatenate([P, np.full((n, B, 1), height)], axis=2).reshape(-1, 3)
        seen = cam.in_view(pts).reshape(n, B)
        uv = cam.project(pts).reshape(n, B, 2)
        uv = uv + rng.normal(0.0, noise_px, uv.shape)
        seen &= rng.random((n, B)) >= miss
        w, h = cam.image_size if cam.image_size is not None else (640, 480)
        n_clutter = rng.poisson(clutter, n)
        for i in range(n):
            src = np.flatnonzero(seen[i])
            fake = np.column_stack(
                [rng.uniform(0, w, n_clutter[i]), rng.uniform(0, h, n_clutter[i])]
            )
            pixels = np.concatenate([uv[i, src], fake])
            source = np.concatenate([src, np.full(n_clutter[i], -1)]).astype(np.int64)
            perm = rng.permutation(len(pixels))
            frames.append(CameraFrameDetections(float(times[i]), k, pixels[perm], source[perm]))
    frames.sort(key=lambda f: (f.t, f.camera))
    return frames


@dataclass(frozen=True)
class TrackingResult:
    """Metrics of a tracking scenario: simulated minutes, bodies in the home (`targets`), the
    calibrated cameras the tracker used (`camera_count`), the MOT metrics, and the RMSE of
    matched people's positions (m) against the twin (`person_rmse_m`) and in the calibrated
    home frame (`person_rmse_in_frame_m`: after the frame's own rigid error, `frame_error_m`
    (largest displacement at a camera) and `frame_error_deg`, is taken out; see
    `frame_alignment`)."""

    scenario: str
    seed: int
    minutes: float
    targets: int
    camera_count: int
    frames: int
    detections: int
    idf1: float
    mota: float
    id_switches: int
    false_positives: int
    misses: int
    max_live_targets: int
    person_rmse_m: float
    person_rmse_in_frame_m: float
    frame_error_m: float
    frame_error_deg: float
    conditions: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


def _walkers_at(scene: Scene, times: Array) -> Array:
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


def _overlap(scene: Scene, duration_s: float) -> float:
    # Seconds two bodies overlapped (a script that makes people meet head-on; 0 in the
    # scenarios' homes): reported so a figure never hides people passing through each other.
    walk = crowd_of(scene.people)
    walk.positions([duration_s])
    return walk.overlap_s


def truth_instants(scene: Scene, duration_s: float) -> tuple[Array, Array]:
    """Return the scoring instants (N,) and the walkers' positions there (N, B, 2)."""
    t = np.arange(0.0, duration_s, 1.0 / SCORE_HZ)
    return t, _walkers_at(scene, t)


def tracking_async(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    minutes: float = 10.0,
    config: TrackerConfig | None = None,
) -> TrackingResult:
    """Run `tracking-async` (module docstring) and return its metrics."""
    scene = tracking_scene(scene)
    rng = np.random.default_rng(seed)
    truth = true_cameras(scene)
    calibrated = calibrated_cameras(scene, seed).first(ASYNC_CAMERAS)
    duration = 60.0 * minutes
    frames = async_camera_frames(scene, truth, duration, rng)
    frames = [f for f in frames if f.camera in calibrated.index]
    tracker = Tracker(calibrated.cameras, config)
    log = TrackLog()
    sigma2 = np.eye(2) * ASYNC_NOISE_PX**2
    for f in frames:
        k = calibrated.index.index(f.camera)
        result = tracker.update(k, f.t, f.pixels, sigma2, heights=ASYNC_HEIGHT_M, kinds="person")
        log.add(result)
    truth_t, truth_xy = truth_instants(scene, duration)
    # A body no calibrated camera could see at an instant is not expected to be tracked there.
    visible = _seen_by_any([truth[i] for i in calibrated.index], truth_xy, ASYNC_HEIGHT_M)
    truth_xy = np.where(visible[..., None], truth_xy, np.nan)
    score = score_tracks(truth_t, truth_xy, log, truth_at=lambda t: _walkers_at(scene, t))
    seen_truth = [truth[i] for i in calibrated.index]
    T = frame_alignment(calibrated.cameras, seen_truth)
    in_frame = score_tracks(
        truth_t, truth_xy, transformed(log, T), truth_at=lambda t: _walkers_at(scene, t)
    )
    shift, turn = frame_error(calibrated.cameras, T)
    return TrackingResult(
        scenario="tracking-async",
        seed=seed,
        minutes=minutes,
        targets=len(scene.people),
        camera_count=len(calibrated.cameras),
        frames=len(frames),
        detections=int(sum(len(f.pixels) for f in frames)),
        idf1=score.idf1,
        mota=score.mota,
        id_switches=score.id_switches,
        false_positives=score.false_positives,
        misses=score.misses,
        max_live_targets=score.max_live_targets,
        person_rmse_m=score.class_rmse_m,
        person_rmse_in_frame_m=in_frame.class_rmse_m,
        frame_error_m=shift,
        frame_error_deg=turn,
        conditions={
            "rate_hz": ASYNC_RATE_HZ,
            "noise_px": ASYNC_NOISE_PX,
            "miss": ASYNC_MISS,
            "clutter_per_frame": ASYNC_CLUTTER,
            "height_m": ASYNC_HEIGHT_M,
            "people_overlap_s": _overlap(scene, duration),
        },
    )


# --------------------------------------------------------------------------------------------
# tracking: rendered images through the detectors


RENDER_RATE_HZ = 5.0
TRACKING_MINUTES = 30.0


@dataclass(frozen=True)
class RenderedFrame:
    """One camera frame of the `tracking` scenario: its capture time (s), the index of its
    camera among the calibrated ones, and what detect_frame found in its image."""

    t: float
    camera: int
    found: tuple[FrameDetection, ...]


def rendered_frames(
    scene: Scene,
    seed: int,
    calibrated: CalibratedCameras,
    *,
    minutes: float = TRACKING_MINUTES,
    rate_hz: float = RENDER_RATE_HZ,
    exposure: ExposureChanges | None = None,
) -> tuple[list[RenderedFrame], Array]:
    """Return the `tracking` scenario's frames in capture order (every calibrated camera at
    `rate_hz` with its own phase, each image rendered with the robot patrolling and the
    walkers, and its detections) and the robot's drive (poses (N, 3) every 0.05 s).
    `exposure`: the cameras' exposure steps (None: a constant exposure)."""
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("the tracking scenario needs a robot with a top marker")
    rng = np.random.default_rng(seed)
    renderer = renderer_for(scene)
    cameras = calibrated.cameras
    duration = 60.0 * minutes
    drive = simulate_patrol(scene.robot, duration + 1.0, dt=0.05, rng=seed)
    pose = np.asarray(drive.pose)
    crowd = crowd_around(scene, pose)
    # The marker's size is the robot's specification, as its colour is.
    marker = MarkerDetectorConfig(
        colour=scene.robot.marker.colour, radius=scene.robot.marker.radius
    )
    mast = mast_config(scene.robot)
    people = {c.name: _background(renderer, scene, c.name) for c in scene.cameras}
    period = 1.0 / rate_hz
    schedule = []
    for k in range(len(cameras)):
        phase = rng.uniform(0.0, period)
        schedule += [(float(t), k) for t in np.arange(phase, duration, period)]
    schedule.sort()
    frames = []
    for t, k in schedule:
        spec = scene.cameras[calibrated.index[k]]
        where = crowd.positions([t])[0]
        walkers = tuple((float(x), float(y)) for x, y in where[1:])
        state = WorldState(t, Pose2D(*robot_poses(crowd, pose, np.array([t]))[0]), walkers)
        if exposure is None:
            image = renderer.render(spec.name, state, rng=rng).image
        else:
            noise = exposure.noise(spec.name, t)
            image = renderer.render(spec.name, state, rng=rng, noise=noise).image
        found = detect_frame(
            image,
            marker=marker,
            marker_height=scene.robot.marker.height,
            people=people[spec.name],
            camera=cameras[k],
            mast=mast,
        )
        frames.append(RenderedFrame(t, k, tuple(found)))
    return frames, np.asarray(drive.pose)


def tracking(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    minutes: float = TRACKING_MINUTES,
    rate_hz: float = RENDER_RATE_HZ,
    config: TrackerConfig | None = None,
) -> TrackingResult:
    """Run `tracking` (module docstring) and return its metrics; `person_rmse_m` is the RMSE
    of matched walkers' positions against their centres where two cameras see them."""
    scene = tracking_scene(scene)
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("the tracking scenario needs a robot with a top marker")
    calibrated = calibrated_cameras(scene, seed)
    frames, drive = rendered_frames(scene, seed, calibrated, minutes=minutes, rate_hz=rate_hz)
    return track_rendered(
        scene, seed, frames, drive, calibrated, minutes=minutes, rate_hz=rate_hz, config=config
    )


def track_rendered(
    scene: Scene,
    seed: int,
    frames: list[RenderedFrame],
    drive: Array,
    calibrated: CalibratedCameras,
    *,
    minutes: float,
    rate_hz: float = RENDER_RATE_HZ,
    config: TrackerConfig | None = None,
    log: TrackLog | None = None,
) -> TrackingResult:
    """Return the `tracking` metrics of `frames` (rendered_frames) run through the one tracker
    (which knows the calibrated cameras and the floor plan); `log`, when given, receives the
    tracks."""
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("the tracking scenario needs a robot with a top marker")
    cameras = calibrated.cameras
    duration = 60.0 * minutes
    occluders = scene_occluders(scene)
    tracker = Tracker(cameras, config, occluders=occluders)
    log = log if log is not None else TrackLog()
    detections = 0
    for f in frames:
        found = f.found
        result = tracker.update(
            f.camera,
            f.t,
            np.array([d.pixel for d in found]).reshape(-1, 2),
            np.array([d.cov for d in found]).reshape(-1, 2, 2),
            heights=[d.height for d in found],
            kinds=[d.kind for d in found],
            labels=[scene.robot.name if d.kind == "robot" else None for d in found],
        )
        log.add(result)
        detections += len(found)
    crowd = crowd_around(scene, drive)
    truth_t = np.arange(0.0, duration, 1.0 / SCORE_HZ)
    bodies = crowd.positions(truth_t)  # the robot, then the walkers
    walkers = bodies[:, 1:]
    truth_xy = np.concatenate([walkers, bodies[:, :1]], axis=1)
    # A body no camera can see (out of every view, or behind a wall) is not expected: its
    # middle (a walker's at half height, the robot's marker) seen by no camera.
    heights = np.array([w.height / 2 for w in scene.people] + [scene.robot.marker.height])
    truth = true_cameras(scene)
    seen_by = _cameras_seeing([truth[i] for i in calibrated.index], truth_xy, heights, occluders)
    truth_xy = np.where(seen_by[..., None] > 0, truth_xy, np.nan)

    def truth_at(times: Array) -> Array:
        # Every body's centre at any time (the robot's drive held while it waits).
        at = crowd.positions(times)
        return np.concatenate([at[:, 1:], at[:, :1]], axis=1)

    # Cameras at 5 Hz update a body seen by one camera every 0.2 s: each track answers with
    # its state moved on to the instant, while it is fresh (not yet coasting).
    coast = (config or TrackerConfig()).coast_after
    options: dict[str, Any] = {
        "classes": np.arange(walkers.shape[1]),
        "truth_at": truth_at,
        "predict_within": coast,
        "rmse_where": seen_by >= 2,
    }
    score = score_tracks(truth_t, truth_xy, log, **options)
    T = frame_alignment(cameras, [truth[i] for i in calibrated.index])
    in_frame = score_tracks(truth_t, truth_xy, transformed(log, T), **options)
    shift, turn = frame_error(cameras, T)
    return TrackingResult(
        scenario="tracking",
        seed=seed,
        minutes=minutes,
        targets=truth_xy.shape[1],
        camera_count=len(cameras),
        frames=len(frames),
        detections=detections,
        idf1=score.idf1,
        mota=score.mota,
        id_switches=score.id_switches,
        false_positives=score.false_positives,
        misses=score.misses,
        max_live_targets=score.max_live_targets,
        person_rmse_m=score.class_rmse_m,
        person_rmse_in_frame_m=in_frame.class_rmse_m,
        frame_error_m=shift,
        frame_error_deg=turn,
        conditions={
            "rate_hz": rate_hz,
            "noise": 1.0,
            "people_overlap_s": crowd.overlap_s,
        },
    )


def mast_config(robot: Robot) -> MarkerDetectorConfig | None:
    """Return the detector settings of the robot's mast marker, None without one."""
    m = robot.mast_marker
    return None if m is None else MarkerDetectorConfig(colour=m.colour)


def _background(renderer: Renderer, scene: Scene, camera: str) -> PersonDetector:
    # The empty home, as an installer records it: no robot, nobody in view.
    away = tuple((1e4, 1e4) for _ in scene.people)
    detector = PersonDetector()
    for i in range(3):
        detector.learn(renderer.render(camera, WorldState(0.0, None, away), rng=i).image)
    return detector


def true_cameras(scene: Scene) -> list[NetworkCamera]:
    """Return the twin's true cameras, for simulating what they see and for scoring only."""
    out = []
    for spec in scene.cameras:
        m = camera_model(spec)
        out.append(
            NetworkCamera.from_pose(m.K, m.dist, m.T_world_camera, (m.width, m.height), m.name)
        )
    return out


@dataclass(frozen=True)
class CalibratedCameras:
    """The cameras as the home knows them after its network calibration: `cameras` (the
    calibrated ones), `index` (each one's index in the scene's cameras) and `rejected` (names
    of the cameras the calibration could not place, which the tracker never hears from)."""

    cameras: list[NetworkCamera]
    index: list[int]
    rejected: tuple[str, ...]

    def first(self, n: int) -> CalibratedCameras:
        """Return the calibrated cameras among the scene's first `n`."""
        keep = [k for k, i in enumerate(self.index) if i < n]
        return CalibratedCameras(
            [self.cameras[k] for k in keep], [self.index[k] for k in keep], self.rejected
        )


_CALIBRATION_CACHE: dict[tuple[str, int], CalibratedCameras] = {}


def calibrated_cameras(scene: Scene, seed: int) -> CalibratedCameras:
    """Return the scene's cameras as its marker network calibration estimates them: each
    camera's own chessboard calibration, then the robot's drive with its odometry
    (core.sim.network_drive.drive_marker_calibration, rendered images), registered to the world
    by its tour of the signposts (core.sim.network_registration). Nothing of the twin's
    true cameras reaches the tracker. Cached per (scene, seed): the drive takes seconds."""
    key = (scene.model_dump_json(), seed)
    hit = _CALIBRATION_CACHE.get(key)
    if hit is not None:
        return hit
    # Imported here: the drive pulls the calibration stack, which the points-only helpers of
    # this module do not need.
    from core.sim.network_drive import drive_marker_calibration
    from core.sim.network_registration import can_register, register_network

    net = drive_marker_calibration(scene, seed).calibration
    if can_register(scene):
        net, _ = register_network(net, scene, seed)
    names = [c.name for c in scene.cameras]
    # A camera's resolution is what its owner knows of it without any calibration.
    sizes = {c.name: (camera_model(c).width, camera_model(c).height) for c in scene.cameras}
    cams = [
        NetworkCamera.from_pose(c.K, c.dist, c.T_world_camera, sizes[c.name], c.name)
        for c in net.cameras
    ]
    result = CalibratedCameras(
        cams, [names.index(c.name) for c in net.cameras], tuple(r.name for r in net.rejected)
    )
    _CALIBRATION_CACHE[key] = result
    return result


def _seen_by_any(
    cameras: list[NetworkCamera],
    xy: Array,
    height: float | Array,
    occluders: Occluders | None = None,
) -> NDArray[np.bool_]:
    """Return (N, B) whether any camera sees each body's point at `height`."""
    return _cameras_seeing(cameras, xy, height, occluders) > 0


def _cameras_seeing(
    cameras: list[NetworkCamera],
    xy: Array,
    height: float | Array,
    occluders: Occluders | None = None,
) -> NDArray[np.int64]:
    """Return (N, B) how many cameras see each body's point at `height` (one value, or one
    per body): in their view and, given occluders, with a clear line of sight."""
    n, b = xy.shape[:2]
    h = np.broadcast_to(np.asarray(height, dtype=np.float64), (b,))
    pts = np.concatenate([xy, np.broadcast_to(h[None, :, None], (n, b, 1))], axis=2)
    pts = pts.reshape(-1, 3)
    count = np.zeros(n * b, dtype=np.int64)
    for cam in cameras:
        ok = cam.in_view(pts)
        if occluders is not None and ok.any():
            ok[ok] = line_of_sight(cam.center[None], pts[ok], occluders)[0]
        count += ok
    return count.reshape(n, b)
