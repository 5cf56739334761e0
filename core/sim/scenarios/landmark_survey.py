"""The `landmark-survey` scenario (spec 04 on the twin): the robot (core.sim.head_robot) tours
the home, reads every landmark it can and builds the semantic and navigation maps.

The survey maps what it reads through the robot's pose estimate: the odometry, fused by an
extended Kalman filter (core.sim.survey_localisation) with the fixes a robot in this home gets
without the twin's truth: a signpost (whose payload carries its world pose) read within
RELOCALISE_M, and, about once a second while the base moves, its top marker located by the
ceiling cameras of the home's installed calibration; each correction is spread back over the
reads since the previous one (_Survey). Routes are kept on the floor plan's frame and followed
through the estimate of the moment, so a fix on the way brings the base back onto them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from itertools import combinations
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.poses import planar_pose
from core.landmarks.detect import LandmarkDetection
from core.landmarks.maps import (
    NavigationMap,
    NoRoute,
    SemanticMap,
    detection_in_world,
)
from core.landmarks.payload import ObjectMark, PayloadError, Signpost, decode_payload
from core.localization import NetworkCamera
from core.sim.head_camera import (
    CALIBRATION_VIEWS,
    calibrate_scene_head_camera,
)
from core.sim.head_robot import (
    FRAME_DT,
    SEARCH_TILT,
    HeadRobot,
    TrackedLandmark,
)
from core.sim.installation import installed_cameras
from core.sim.scene import Scene, default_scene
from core.sim.survey_localisation import (
    CEILING_HZ,
    CeilingLocaliser,
)

Array = NDArray[np.float64]

# The default home's survey tour (x, y metres): straight legs through free floor and the doors,
# living room, kitchen, bedroom; the head sweeps at every stop.
DEFAULT_TOUR = (
    (1.0, 1.2),
    (2.5, 2.2),
    (3.3, 4.6),
    (3.0, 3.5),
    (0.8, 3.2),
    (3.8, 1.45),
    (5.2, 1.45),
    (5.2, 1.0),
    (7.3, 1.05),
    (7.3, 2.5),
    (6.55, 2.55),
    (6.55, 3.45),
    (7.3, 3.45),
    (5.2, 3.5),
    (5.2, 4.4),
)
SWEEP_PANS = tuple(float(a) for a in np.linspace(-2.8, 2.8, 15))
SURVEY_READ_TIMEOUT_S = 40.0
# Reads tried of one located landmark, at most: a read that failed (a long way round the
# furniture within the timeout, a view hidden at the reading pose) is tried again when the
# landmark is located again from a later stop.
SURVEY_READ_TRIES = 2
SEPARATE_M = 0.45  # m: a located landmark nearer than this to a known one of its kind is that one
MATCH_TRUTH_M = 0.5  # m: scoring: a map entry this near its landmark (and of its id) is right


@dataclass(frozen=True)
class SurveyRoute:
    """A route of the navigation map between two rooms: the places, their rooms, length m
    (None and `error` when there is none)."""

    from_room: str
    to_room: str
    places: tuple[int, ...] | None
    rooms: tuple[str, ...] | None
    length_m: float | None
    error: str | None = None


@dataclass(frozen=True)
class LandmarkSurveyResult:
    """Metrics of `landmark-survey`: object marks found / present / seen in the drive (drawn
    whole in at least one head-camera frame), signpost places found / present / seen, the
    semantic map's mean and max position error against the twin (m), false entries (an id no
    landmark carries, or more than MATCH_TRUTH_M from its landmark) and duplicates (two entries
    of one landmark), landmarks seen but not read, the reads attempted by PBVS and their
    successes, the drive's time (s), whether it finished the tour (not cut short by a
    duration) and whether the base ever touched a wall or furniture (scored on the true pose),
    its frames, the odometry's final drift (m) and the final pose estimate's position error
    (m), the ceiling fixes (rate, frames rendered, fixes applied and refused, cameras; empty
    without them), routes between every pair of rooms, and both maps (GeoJSON-like)."""

    scenario: str
    seed: int
    objects_present: int
    objects_seen: int
    objects_found: int
    places_present: int
    places_seen: int
    places_found: int
    position_error_mean_m: float | None
    position_error_max_m: float | None
    false_entries: int
    duplicate_entries: int
    seen_not_read: tuple[str, ...]
    reads_attempted: int
    reads_succeeded: int
    time_s: float
    completed: bool
    collided: bool
    frames: int
    odometry_drift_m: float
    pose_error_m: float
    ceiling: dict[str, float | int]
    calibration_rms_px: float
    routes: tuple[SurveyRoute, ...]
    goals: dict[str, Any]
    semantic_map: dict[str, Any]
    navigation_map: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


def _se2_log(D: Array) -> Array:
    """Return (theta, u) (3,) of a planar rigid transform D (4, 4): D = exp(theta, u)."""
    th = float(np.arctan2(D[1, 0], D[0, 0]))
    V = _se2_V(th)
    return np.array([th, *np.linalg.solve(V, D[:2, 3])])


def _se2_V(th: float) -> Array:
    if abs(th) < 1e-9:
        return np.eye(2)
    a, b = np.sin(th) / th, (1.0 - np.cos(th)) / th
    return np.array([[a, -b], [b, a]])


def _se2_exp(x: Array) -> Array:
    """Return the planar rigid transform (4, 4) exp(theta, u) of x = (theta, u)."""
    T = planar_pose((0.0, 0.0, float(x[0])))
    T[:2, 3] = _se2_V(float(x[0])) @ x[1:]
    return T


@dataclass(frozen=True)
class SurveyRead:
    """An object mark or signpost the survey read, as it enters the maps: the record, the
    mark's world pose T_world_mark (4, 4) with the (6, 6) covariance of (rotation
    perturbation, position) (the detection's, the camera pose held exact), the simulated time
    of the read (s) and the camera-to-mark distance (m)."""

    record: ObjectMark | Signpost
    T_world_mark: Array
    cov: Array
    time: float
    distance: float


@dataclass
class _Read:
    """An object mark read, kept on the odometry: the detection, the camera pose it was seen
    from (odometry frame), the time, the drift clock, and the relocalisations before it."""

    det: LandmarkDetection
    T_odom_cam: Array
    time: float
    clock: float
    fixes: int
    W: Array


class _Survey:
    """The survey's state: the robot, both maps and the places where unread landmarks were
    located (odometry frame).

    Object marks are mapped through the robot's pose estimate, the odometry corrected by every
    fix (a signpost read, HeadRobot.relocalise; the ceiling cameras while the base moves,
    core.sim.survey_localisation). The odometry drifts between two corrections; when
    the second comes, its correction D is spread back along the reads made since the first,
    in proportion to the drift clock (metres driven plus radians turned, the slip model's
    variance being linear in both): a read at a fraction lam of the way gets exp(lam log D),
    the Brownian-bridge estimate of the drift it was made with. The semantic map is rebuilt
    from the reads so corrected; reads reach `on_read` once the correction after them is
    known (or at the end of the survey)."""

    def __init__(
        self, robot: HeadRobot, on_read: Callable[[SurveyRead], None] | None = None
    ) -> None:
        self.robot = robot
        self.semantic = SemanticMap()
        self.navigation = NavigationMap()
        self.tried: list[tuple[str, Array]] = []  # (kind, world position) of failed reads
        self.attempts = 0
        self.successes = 0
        self.reads: list[_Read] = []
        self.fixes = robot.fixes  # (clock, W before, W after), HeadRobot._correct
        self.synced = 0  # the fixes the semantic map has taken in
        self.emitted = 0
        self.on_read = on_read

    def _world(self, read: _Read) -> Array:
        """Return T_world_odom at a read: its estimate then, with the next relocalisation's
        correction spread back to it (class docstring)."""
        if read.fixes >= len(self.fixes):
            return read.W
        clock, W_old, W_new = self.fixes[read.fixes]
        prev = self.fixes[read.fixes - 1][0] if read.fixes else 0.0
        lam = float(np.clip((read.clock - prev) / max(clock - prev, 1e-9), 0.0, 1.0))
        D = W_new @ np.linalg.inv(W_old)
        return _se2_exp(lam * _se2_log(D)) @ read.W

    def _entry(self, read: _Read) -> SurveyRead:
        T, C = detection_in_world(read.det, self._world(read) @ read.T_odom_cam)
        assert read.det.record is not None
        return SurveyRead(
            read.det.record, T, C, read.time, float(np.linalg.norm(read.det.position))
        )

    def _rebuild(self) -> None:
        self.semantic = SemanticMap()
        for read in self.reads:
            e = self._entry(read)
            assert isinstance(e.record, ObjectMark)
            self.semantic.observe(e.record, e.T_world_mark, e.cov, e.time)

    def flush(self, settled: bool = True) -> None:
        """Hand the reads whose pose is settled (a fix came after them), or all (`settled`
        False, at the end), to `on_read`."""
        n = len(self.reads)
        if settled:
            n = self.emitted
            while n < len(self.reads) and self.reads[n].fixes < len(self.fixes):
                n += 1
        if self.on_read is not None:
            for read in self.reads[self.emitted : n]:
                self.on_read(self._entry(read))
        self.emitted = n

    def sync(self) -> None:
        """Rebuild the semantic map when fixes came since it was built, and hand on the reads
        they settled."""
        if self.synced < len(self.fixes):
            self.synced = len(self.fixes)
            self._rebuild()
            self.flush()

    def known(self, p_odom: Array, kind: str) -> bool:
        """Return whether a located position (3,) in the odometry frame is a landmark of its
        kind ("object" or "signpost", told by the outer pattern) already mapped, or tried
        SURVEY_READ_TRIES times: an object mark may hang beside a signpost (the default
        home's clock is 0.41 m from one)."""
        self.sync()
        p = (self.robot.T_world_odom @ np.append(p_odom, 1.0))[:3]
        if kind == "object":
            near = [o.position for o in self.semantic.objects]
        else:
            g = self.navigation.graph
            near = [np.asarray(g.nodes[k]["xyz"]) for k in g]
        if any(float(np.linalg.norm(p - q)) < SEPARATE_M for q in near):
            return True
        tries = sum(
            1 for k, q in self.tried if k == kind and float(np.linalg.norm(p - q)) < SEPARATE_M
        )
        return tries >= SURVEY_READ_TRIES

    def record(self, det: LandmarkDetection, T_odom_cam: Array) -> None:
        """Put a decoded detection in its map (class docstring); a signpost read near enough
        also corrects the odometry."""
        r = self.robot
        rec = det.record
        self.sync()
        if isinstance(rec, ObjectMark):
            read = _Read(det, T_odom_cam, r.time, r.drift_clock, len(self.fixes), r.T_world_odom)
            self.reads.append(read)
            e = self._entry(read)
            self.semantic.observe(rec, e.T_world_mark, e.cov, e.time)
        elif isinstance(rec, Signpost):
            self.navigation.observe(rec)
            W = r.T_world_odom
            if self.on_read is not None:
                T, C = detection_in_world(det, W @ T_odom_cam)
                self.on_read(SurveyRead(rec, T, C, r.time, float(np.linalg.norm(det.position))))
            if r.relocalise(det, T_odom_cam):
                self.sync()

    def sweep(self) -> list[TrackedLandmark]:
        """Sweep the head over SWEEP_PANS; map what is read; return the unread, unknown
        landmarks located (nearest first)."""
        r = self.robot
        todo: list[tuple[float, TrackedLandmark]] = []
        for pan in SWEEP_PANS:
            while abs(r.pan - pan) > 1e-9 or abs(r.tilt - SEARCH_TILT) > 1e-9:
                r.aim(pan, SEARCH_TILT, FRAME_DT)
                r.drive(0.0, 0.0, FRAME_DT)
            for d in r.look():
                T = r.locate(d)
                if d.record is not None:
                    self.record(d, r.T_odom_cam())
                    continue
                if not self.known(T[:3, 3], d.kind) and not any(
                    t.kind == d.kind and float(np.linalg.norm(T[:3, 3] - t.T[:3, 3])) < SEPARATE_M
                    for _, t in todo
                ):
                    dist = float(np.linalg.norm(d.position))
                    todo.append((dist, r.track(d)))
            r.drive(0.0, 0.0, FRAME_DT)
        todo.sort(key=lambda x: x[0])
        return [t for _, t in todo if not self.known(t.T[:3, 3], t.kind)]

    def go(self, target: Array, timeout: float = 120.0) -> None:
        """Drive the base to a floor point (x, y), world frame, along a route planned on the
        floor plan (HeadRobot.go_to) on the odometry (corrected by T_world_odom), for at most
        `timeout` s."""
        if timeout > 0:
            self.robot.go_to(np.asarray(target, dtype=np.float64), timeout)


def landmark_survey(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    tour: tuple[tuple[float, float], ...] | None = None,
    calibration_views: int = CALIBRATION_VIEWS,
    duration_s: float | None = None,
    on_progress: Callable[[str, float], None] | None = None,
    on_read: Callable[[SurveyRead], None] | None = None,
    ceiling_hz: float = CEILING_HZ,
    cameras: Sequence[NetworkCamera] | None = None,
) -> LandmarkSurveyResult:
    """Return the metrics of `landmark-survey`: the robot drives `tour` (default: DEFAULT_TOUR
    on the default home, else the robot's patrol) along routes planned on the floor plan,
    sweeps its head at every stop, maps every landmark it reads, and reads by PBVS
    (HeadRobot.read, up to SURVEY_READ_TIMEOUT_S) every landmark it located but could not
    read, coming back to the stop afterwards. Poses come from the odometry (started at the
    robot's known start pose), corrected at signposts and by the robot's top marker located
    by the ceiling cameras (core.sim.survey_localisation, _Survey), and the calibrated head
    camera; the twin's truth only scores the maps.

    ceiling_hz: ceiling frames a second while the base moves (0: no ceiling fixes, the
    odometry and the signposts alone); cameras: the calibrated ceiling cameras (default: the
    home's installed calibration, core.sim.installation; never the twin's true cameras).

    duration_s: stop after this much simulated time (the tour cut short); on_progress(phase,
    fraction) is called as the survey goes from stop to stop and read to read; on_read gets
    every read as it enters the maps (object marks once their pose is settled, _Survey).
    """
    if calibration_views < 3:
        raise InvalidInput("landmark-survey needs calibration_views >= 3")
    if duration_s is not None and not (np.isfinite(duration_s) and duration_s > 0):
        raise InvalidInput(f"duration_s must be a positive number of seconds, got {duration_s}")
    sc = scene if scene is not None else default_scene()
    if tour is None:
        if scene is None:
            tour = DEFAULT_TOUR
        elif sc.robot is not None and sc.robot.patrol:
            tour = tuple((float(x), float(y)) for x, y in sc.robot.patrol)
        else:
            raise InvalidInput("landmark-survey needs a tour or a robot with patrol waypoints")
    stops = np.asarray(tour, dtype=np.float64)
    if stops.ndim != 2 or stops.shape[1] != 2 or len(stops) < 1:
        raise InvalidInput(f"tour must be (x, y) points, got shape {stops.shape}")
    if not (np.isfinite(ceiling_hz) and ceiling_hz >= 0):
        raise InvalidInput(f"ceiling_hz must be a number >= 0, got {ceiling_hz}")
    rng = np.random.default_rng(seed)
    K, dist, rms = calibrate_scene_head_camera(sc, rng, calibration_views)
    ceiling = None
    if ceiling_hz > 0 and sc.robot is not None and sc.robot.marker is not None:
        cams = installed_cameras(sc) if cameras is None else list(cameras)
        ceiling = CeilingLocaliser(
            sc, cams, rate_hz=ceiling_hz, rng=np.random.default_rng([seed, 1])
        )
    robot = HeadRobot(sc, K, dist, rng=rng, ceiling=ceiling)
    survey = _Survey(robot, on_read)
    end = np.inf if duration_s is None else float(duration_s)
    n = len(stops)

    def progress(k: int, what: str) -> None:
        if on_progress is not None:
            done = max(k / n, min(robot.time / end, 1.0))
            on_progress(f"stop {k + 1} of {n}: {what}", float(done))

    completed = True
    for k, stop in enumerate(stops):
        if robot.time >= end:
            completed = False
            break
        progress(k, "driving")
        survey.go(stop, min(120.0, end - robot.time))
        if robot.time >= end:
            completed = False
            break
        progress(k, "sweeping the head")
        tracks = survey.sweep()
        for j, track in enumerate(tracks):
            if survey.known(track.T[:3, 3], track.kind):
                continue  # read meanwhile, from another reading pose
            left = end - robot.time
            if left <= 0:
                break
            progress(k, f"reading landmark {j + 1} of {len(tracks)} located")
            survey.attempts += 1
            out = robot.read(track, min(SURVEY_READ_TIMEOUT_S, left))
            if out.read and out.detection is not None and out.T_odom_cam is not None:
                survey.successes += 1
                survey.record(out.detection, out.T_odom_cam)
            else:
                survey.tried.append((track.kind, (robot.T_world_odom @ track.T[:, 3])[:3]))
            survey.go(stop, min(120.0, end - robot.time))
    survey.sync()
    survey.flush(settled=False)
    return _score_survey(sc, survey, seed, rms, completed and robot.time < end)


def _score_survey(
    sc: Scene, survey: _Survey, seed: int, rms: float, completed: bool
) -> LandmarkSurveyResult:
    robot = survey.robot
    marks = robot.landmarks
    ids: dict[int, int] = {}
    for k, lm in enumerate(marks):
        try:
            ids[decode_payload(lm.text).id] = k
        except PayloadError:
            continue
    errors: list[float] = []
    false = 0
    hits: dict[int, int] = {}
    for obj in survey.semantic.objects:
        j = ids.get(obj.id)
        if j is None or marks[j].kind != "object":
            false += 1
            continue
        k = j
        e = float(np.linalg.norm(obj.position - marks[k].T_world_mark[:3, 3]))
        if e > MATCH_TRUTH_M:
            false += 1
            continue
        errors.append(e)
        hits[k] = hits.get(k, 0) + 1
    graph = survey.navigation.graph
    for place in graph.nodes:
        j = ids.get(int(place))
        if j is None or marks[j].kind != "signpost":
            false += 1
            continue
        hits[j] = hits.get(j, 0) + 1
    duplicates = sum(n - 1 for n in hits.values())
    kinds = [lm.kind for lm in marks]
    seen = robot.seen
    rooms = [r.name for r in sc.rooms]
    routes = []
    for a, b in combinations(rooms, 2):
        try:
            rt = survey.navigation.route(a, b)
            routes.append(SurveyRoute(a, b, rt.places, rt.rooms, rt.length_m))
        except NoRoute as exc:
            routes.append(SurveyRoute(a, b, None, None, None, str(exc)))
    true = robot.base.state.pose
    odo = robot.base.state.odometry
    seen_not_read = tuple(sorted(marks[k].name for k in seen if k not in hits))
    n_obj = sum(1 for k in hits if kinds[k] == "object")
    n_place = sum(1 for k in hits if kinds[k] == "signpost")
    goals = {
        "every_seen_landmark_mapped": not seen_not_read,
        "no_false_or_duplicate_entries": false == 0 and duplicates == 0,
        "route_between_every_pair_of_rooms": all(r.places is not None for r in routes),
        "no_collision": not robot.collided,
    }
    return LandmarkSurveyResult(
        scenario="landmark-survey",
        seed=seed,
        objects_present=kinds.count("object"),
        objects_seen=sum(1 for k in seen if kinds[k] == "object"),
        objects_found=n_obj,
        places_present=kinds.count("signpost"),
        places_seen=sum(1 for k in seen if kinds[k] == "signpost"),
        places_found=n_place,
        position_error_mean_m=float(np.mean(errors)) if errors else None,
        position_error_max_m=max(errors) if errors else None,
        false_entries=false,
        duplicate_entries=duplicates,
        seen_not_read=seen_not_read,
        reads_attempted=survey.attempts,
        reads_succeeded=survey.successes,
        time_s=robot.time,
        completed=completed,
        collided=robot.collided,
        frames=robot.frames,
        odometry_drift_m=float(np.hypot(true.x - odo.x, true.y - odo.y)),
        pose_error_m=float(np.hypot(*(robot.estimate()[:2] - (true.x, true.y)))),
        ceiling=robot.ceiling.summary() if robot.ceiling is not None else {},
        calibration_rms_px=float(rms),
        routes=tuple(routes),
        goals=goals,
        semantic_map=survey.semantic.to_dict(),
        navigation_map=survey.navigation.to_dict(),
    )
