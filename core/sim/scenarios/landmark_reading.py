"""The `landmark-reading` scenario (spec 04 on the twin): a landmark located and read by the
robot's head camera by position-based visual servoing (core.sim.head_robot: `HeadRobot.read`)
from random start poses in the home.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.geometry.polygon import points_in_polygons
from core.geometry.poses import planar_pose
from core.geometry.rotations import wrap_angle
from core.localization.occluders import line_of_sight
from core.sim._geometry import yaw_matrix
from core.sim.head_camera import (
    CALIBRATION_VIEWS,
    calibrate_scene_head_camera,
)
from core.sim.head_robot import (
    READ_TIMEOUT_S,
    HeadRobot,
    TrackedLandmark,
)
from core.sim.scenarios.records import percent_or_none, percentile_or_none
from core.sim.scene import Scene, default_scene

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ReadingTrial:
    """One `landmark-reading` trial: the landmark (scene name, kind), the true start (x, y,
    yaw), its distance (m) and bearing off the mark's normal (deg), whether it was read (the
    right landmark, within the time limit, without touching a wall or furniture), the time to
    read (s, None when unread), the frames, the final task error, whether the base collided,
    and the landmark whose record it decoded (`read_landmark`: its scene name, None when
    nothing was decoded; another than `landmark` is a failure)."""

    landmark: str
    kind: str
    start: tuple[float, float, float]
    distance: float
    bearing_deg: float
    read: bool
    time_to_read: float | None
    frames: int
    final_translation_error: float | None
    final_rotation_error_deg: float | None
    collided: bool
    read_landmark: str | None = None


@dataclass(frozen=True)
class LandmarkReadingResult:
    """Metrics of `landmark-reading`: success rate (%) over the trials, times to read (median,
    95th percentile, max, s), per kind, the collisions, the trials that read another landmark
    than theirs (`wrong_landmark_reads`, failures), the landmarks for which some draw found
    no start (another landmark was drawn instead), the goal (spec 04: >= 95 % within 60 s),
    the head camera's calibration RMS (px) and every trial."""

    scenario: str
    seed: int
    trials: int
    success_pct: float
    time_to_read_median: float | None
    time_to_read_p95: float | None
    time_to_read_max: float | None
    success_pct_by_kind: dict[str, float | None]
    collisions: int
    wrong_landmark_reads: int
    landmarks_without_start: tuple[str, ...]
    calibration_rms_px: float
    goals: dict[str, Any]
    runs: tuple[ReadingTrial, ...]

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


START_DISTANCE = {"object": (0.8, 2.5), "signpost": (0.8, 4.0)}  # m, horizontal, from the mark
START_BEARING_DEG = 60.0  # start within this of the mark's normal
START_CLEARANCE = 0.1  # m between the base and any wall or furniture at the start
# The trial's landmark as the robot's map holds it: off its true pose by these (per floor axis,
# and in yaw), as a survey's semantic map locates it (landmark-survey: a few centimetres).
READ_PRIOR_M = 0.1
READ_PRIOR_RAD = 0.1


def _start_pose(
    robot: HeadRobot, k: int, rng: np.random.Generator
) -> tuple[Array, float, float] | None:
    """Return a random free start (x, y, yaw) in front of landmark k with its distance and
    bearing, the mark in the head's line of sight (None if 200 draws find none)."""
    lm = robot.landmarks[k]
    m = lm.T_world_mark[:3, 3]
    n = lm.T_world_mark[:3, 2].copy()
    n[2] = 0.0
    n /= np.linalg.norm(n)
    lo, hi = START_DISTANCE[lm.kind]
    head = np.asarray(robot.head.position)
    for _ in range(200):
        r = rng.uniform(lo, hi)
        b = np.radians(rng.uniform(-START_BEARING_DEG, START_BEARING_DEG))
        p = m[:2] + r * (yaw_matrix(b)[:2, :2] @ n[:2])
        to_mark = np.arctan2(m[1] - p[1], m[0] - p[0])
        yaw = wrap_angle(to_mark + rng.uniform(-np.pi / 2, np.pi / 2))
        if (
            robot.clearance(p) < START_CLEARANCE
            or not points_in_polygons(
                p[None, :2], [room.polygon for room in robot.scene.rooms]
            ).any()
        ):
            continue
        eye = planar_pose((p[0], p[1], yaw)) @ np.append(head, 1.0)
        if not line_of_sight(eye[None, :3], m[None], robot.occluders)[0, 0]:
            continue
        return np.array([p[0], p[1], yaw]), float(r), float(np.degrees(b))
    return None


def landmark_reading(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    trials: int = 100,
    calibration_views: int = CALIBRATION_VIEWS,
    timeout: float = READ_TIMEOUT_S,
) -> LandmarkReadingResult:
    """Return the metrics of `landmark-reading`: PBVS reading from `trials` random starts.

    Each trial picks one of the scene's landmarks at random and a free start 0.8-2.5 m
    (object marks) or 0.8-4 m (signposts) from it (another landmark when 200 draws find
    none), within 60 deg of its normal, with the mark in the head's line of sight (furniture
    may stand between the base and the reading pose: the approach is planned on the floor
    plan) and the robot turned up to 90 deg away from it. Every landmark of the home is drawn
    in every frame, as it hangs. The robot is told which landmark to read as its map holds it
    (its pose READ_PRIOR_M and READ_PRIOR_RAD off the truth, a landmark located before) and
    reads it with HeadRobot.read (calibrated head camera, odometry from the known start, the
    floor plan as its map), which tracks the detection of its kind nearest that pose (within
    MATCH_RADIUS); a trial succeeds when the decoded record is the trial's landmark's own
    (reading another is a failure, counted in `wrong_landmark_reads`), within `timeout` simulated
    seconds, and the base never touched a wall or furniture (scored on the true pose).
    """
    if trials < 1 or calibration_views < 3 or not timeout > 0:
        raise InvalidInput(
            "landmark-reading needs trials >= 1, calibration_views >= 3 and timeout > 0"
        )
    sc = scene if scene is not None else default_scene()
    rng = np.random.default_rng(seed)
    K, dist, rms = calibrate_scene_head_camera(sc, rng, calibration_views)
    robot = HeadRobot(sc, K, dist, rng=rng)
    if not robot.landmarks:
        raise InvalidInput(f"scene {sc.name!r} has no landmarks to read")
    runs = []
    no_start: set[str] = set()
    for _ in range(trials):
        drawn = None
        for _ in range(10 * len(robot.landmarks)):
            k = int(rng.integers(len(robot.landmarks)))
            drawn = _start_pose(robot, k, rng)
            if drawn is not None:
                break
            no_start.add(robot.landmarks[k].name)
        if drawn is None:
            raise InvalidInput(f"no free start in front of any landmark of scene {sc.name!r}")
        start, r, b = drawn
        robot = HeadRobot(sc, K, dist, start=start, rng=rng)
        # The trial's landmark as the robot's map holds it (located before, READ_PRIOR_* off):
        # the robot reads the landmark it locates nearest that, never the truth itself.
        T_prior = robot.landmarks[k].T_world_mark.copy()
        T_prior[:2, 3] += rng.normal(0.0, READ_PRIOR_M, 2)
        T_prior[:3, :3] = yaw_matrix(float(rng.normal(0.0, READ_PRIOR_RAD))) @ T_prior[:3, :3]
        res = robot.read(TrackedLandmark(T_prior, robot.landmarks[k].kind, robot.time), timeout)
        collided = robot.collided
        lm = robot.landmarks[k]
        text = res.detection.text if res.read and res.detection is not None else None
        right = text is not None and text == lm.text
        read_name = next((m.name for m in robot.landmarks if m.text == text), text)
        runs.append(
            ReadingTrial(
                landmark=lm.name,
                kind=lm.kind,
                start=(float(start[0]), float(start[1]), float(start[2])),
                distance=r,
                bearing_deg=b,
                read=bool(right and not collided),
                time_to_read=float(res.time) if right else None,
                frames=res.frames,
                final_translation_error=res.final_translation_error,
                final_rotation_error_deg=res.final_rotation_error_deg,
                collided=collided,
                read_landmark=read_name,
            )
        )
    times = [t.time_to_read for t in runs if t.read and t.time_to_read is not None]
    ok = sum(t.read for t in runs)
    by_kind: dict[str, float | None] = {}
    for kind in ("object", "signpost"):
        mine = [t for t in runs if t.kind == kind]
        by_kind[kind] = percent_or_none(sum(t.read for t in mine), len(mine))
    success = 100.0 * ok / len(runs)
    return LandmarkReadingResult(
        scenario="landmark-reading",
        seed=seed,
        trials=trials,
        success_pct=success,
        time_to_read_median=percentile_or_none(times, 50),
        time_to_read_p95=percentile_or_none(times, 95),
        time_to_read_max=max(times) if times else None,
        success_pct_by_kind=by_kind,
        collisions=sum(t.collided for t in runs),
        wrong_landmark_reads=sum(
            t.read_landmark is not None and t.read_landmark != t.landmark for t in runs
        ),
        landmarks_without_start=tuple(sorted(no_start)),
        calibration_rms_px=float(rms),
        goals={"success_pct_min": 95.0, "within_s": timeout, "met": success >= 95.0},
        runs=tuple(runs),
    )
