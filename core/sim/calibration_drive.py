"""The robot's calibration drive in the twin: a programme of stops over the free floor.

The robot really drives from its start pose to a programme of stops over the free floor
(`plan_stops`; shortest paths through the doors, `core.sim._floor.FloorRoutes`), steered by its
odometry, as the unicycle with wheel slip of core.sim.motion (`Driver`, `drive_stops`); at each
stop it waits `dwell` seconds for the images. What the calibration is told is the odometry
between the stops (core.calibration.network.odometry_prior) with its covariance from the base's
slip model (`Drive.odometry`); where it really stood (`Drive.true_poses`) is for scoring only.
`revisit_stops` plans a second pass over more of a camera's view, from its detections alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from core.calibration.network import (
    OdometryPrior,
    SlipModel,
    odometry_prior,
)
from core.errors import InvalidInput
from core.sim._floor import FloorRoutes, inside
from core.sim.motion import Patrol, UnicycleBase
from core.sim.scene import Scene

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Drive:
    """A driven programme of stops: `true_poses` (M, 3) where the robot really stood (scoring
    only), `odometry` the prior the calibration gets (start pose, increments, covariance),
    `times` (M,) s at which the images were taken, `duration_s` the whole drive's simulated
    time, `length_m` the distance driven (by odometry), `path_true` and `path_odometry`
    (N, 3) every step's true and odometry pose (for display)."""

    true_poses: Array
    odometry: OdometryPrior
    times: Array
    duration_s: float
    length_m: float
    path_true: Array = field(repr=False)
    path_odometry: Array = field(repr=False)


def plan_stops(
    scene: Scene, stops: int, rng: np.random.Generator, *, order: str = "nearest"
) -> Array:
    """Return `stops` floor positions (M, 2) spread over the free floor, in the order the robot
    visits them: a first straight leg ahead of the start pose (two stops 0.4 and 0.8 m ahead,
    where free), then the others nearest first (`order` "nearest") or in random order
    ("random": more crossings between the rooms, a much longer drive)."""
    if scene.robot is None:
        raise InvalidInput("a calibration drive needs a scene with a robot")
    routes = FloorRoutes(scene, scene.robot.base_radius + 0.1, spacing=0.1)
    cand = routes.points[rng.permutation(len(routes.points))]
    # The first leg goes straight ahead from the start: the only motion whose odometry ties
    # the start's heading (the world frame's x axis) to what the cameras see, before turns
    # add their heading noise.
    x0, y0, yaw0 = scene.robot.start
    lead: list[Array] = []
    for d in (0.4, 0.8):
        p = np.array([x0 + d * math.cos(yaw0), y0 + d * math.sin(yaw0)])
        if np.min(np.sum((routes.points - p) ** 2, axis=1)) <= 0.08**2 and len(lead) < stops:
            lead.append(p)
    # Spread over the floor: stops at least 0.6 of the mean spacing apart (of the free floor's
    # area shared out), relaxed when the floor cannot hold that many.
    sep = 0.6 * math.sqrt(0.01 * len(routes.points) / max(stops, 1))
    chosen: list[Array] = []
    while len(chosen) + len(lead) < stops and sep > 0.05:
        for p in cand:
            if len(chosen) + len(lead) >= stops:
                break
            near = [*lead, *chosen]
            if not near or np.min(np.sum((np.array(near) - p) ** 2, axis=1)) >= sep**2:
                chosen.append(p)
        sep *= 0.7
    pts = np.array(chosen).reshape(-1, 2)
    if order == "random":
        return np.vstack([np.array(lead).reshape(-1, 2), pts])
    if order != "nearest":
        raise InvalidInput(f"unknown stop order {order!r}; use 'nearest' or 'random'")
    visit = []
    here = lead[-1] if lead else np.array(scene.robot.start[:2])
    left = list(range(len(pts)))
    while left:
        k = min(left, key=lambda i: float(np.sum((pts[i] - here) ** 2)))
        visit.append(k)
        left.remove(k)
        here = pts[k]
    return np.vstack([np.array(lead).reshape(-1, 2), pts[visit]])


class Driver:
    """The scene's robot driving a calibration programme, resumable stop by stop.

    The base (UnicycleBase: limits, wheel slip drawn from `rng`) follows the shortest free path
    to each stop (Patrol, steered by its odometry), brakes, and waits `dwell` seconds; the stop
    is recorded when it stands still. A segment is abandoned after `max_segment_s` seconds
    (the robot stops where it is).
    """

    def __init__(
        self,
        scene: Scene,
        rng: np.random.Generator,
        *,
        dt: float = 0.05,
        dwell: float = 1.0,
        max_segment_s: float = 120.0,
    ) -> None:
        if scene.robot is None:
            raise InvalidInput("a calibration drive needs a scene with a robot")
        self.robot = scene.robot
        self.routes = FloorRoutes(scene, self.robot.base_radius + 0.05, spacing=0.1)
        self.base = UnicycleBase.from_robot(self.robot, dt=dt, rng=rng)
        self.dt, self.dwell, self.max_segment_s = dt, dwell, max_segment_s
        self.true_path = [self.base.state.pose.as_array()]
        self.odo_path = [self.base.state.odometry.as_array()]
        self.idx: list[int] = []
        self.times: list[float] = []

    def visit(self, stops: Array) -> None:
        """Drive through the floor positions `stops` (K, 2) in order."""
        base, dt = self.base, self.dt
        for goal in np.asarray(stops, dtype=np.float64).reshape(-1, 2):
            here = np.array([base.state.odometry.x, base.state.odometry.y])
            path = self.routes.path(here, goal)
            patrol = Patrol(path, self.robot.limits, loop=False, tolerance=0.1)
            for _ in range(round(self.max_segment_s / dt)):
                st = base.step(*patrol.command(base.state.odometry))
                self.true_path.append(st.pose.as_array())
                self.odo_path.append(st.odometry.as_array())
                if patrol.done and st.v == 0.0 and st.omega == 0.0:
                    break
            for _ in range(round(self.dwell / dt)):
                st = base.step(0.0, 0.0)
                self.true_path.append(st.pose.as_array())
                self.odo_path.append(st.odometry.as_array())
            self.idx.append(len(self.odo_path) - 1)
            self.times.append(base.state.time)

    def drive(self) -> Drive:
        """Return the drive so far (at least one stop)."""
        if not self.idx:
            raise InvalidInput("the robot has not stopped anywhere yet")
        odo = np.array(self.odo_path)
        tru = np.array(self.true_path)
        slip = SlipModel(**self.robot.slip.model_dump())
        prior = odometry_prior(odo, self.idx, slip)
        length = float(np.sum(np.linalg.norm(np.diff(odo[:, :2], axis=0), axis=1)))
        return Drive(
            tru[self.idx], prior, np.array(self.times), self.base.state.time, length, tru, odo
        )


def drive_stops(scene: Scene, stops: Array, rng: np.random.Generator, **options: float) -> Drive:
    """Return the drive of the scene's robot from its start pose through `stops` (M, 2)
    (`Driver`; options dt, dwell, max_segment_s)."""
    driver = Driver(scene, rng, **options)
    driver.visit(stops)
    return driver.drive()


def revisit_stops(
    routes: FloorRoutes, seen_xy: Array, count: int, rng: np.random.Generator
) -> Array:
    """Return up to `count` new stops (K, 2) spread over the free floor within 0.3 m (0.8 m
    when fewer than 6) of the convex hull of `seen_xy` (the odometry positions where a camera
    saw the marker): more of that camera's view, known from its detections alone."""
    if count <= 0 or len(seen_xy) == 0:
        return np.zeros((0, 2))
    pts = routes.points
    # A few detections outline the view poorly: reach further around them.
    reach = 0.3 if len(seen_xy) >= 6 else 0.8
    if len(seen_xy) >= 3:
        hull = cv2.convexHull(seen_xy.astype(np.float32)).reshape(-1, 2).astype(np.float64)
        a, b = hull, np.roll(hull, -1, axis=0)
        d = b - a
        t = np.clip(
            np.einsum("pkj,kj->pk", pts[:, None, :] - a[None], d) / np.sum(d * d, axis=1), 0, 1
        )
        dist = np.min(np.linalg.norm(pts[:, None, :] - (a + t[..., None] * d), axis=2), axis=1)
        near = inside(pts, hull) | (dist <= reach)
    else:
        near = np.min(np.linalg.norm(pts[:, None, :] - seen_xy[None], axis=2), axis=1) <= reach
    cand = pts[near][rng.permutation(int(near.sum()))]
    out: list[Array] = []
    sep = 0.6 * math.sqrt(0.01 * len(cand) / count) if len(cand) else 0.0
    while len(out) < min(count, len(cand)) and sep > 0.02:
        for p in cand:
            if len(out) >= count:
                break
            if not out or np.min(np.sum((np.array(out) - p) ** 2, axis=1)) >= sep**2:
                out.append(p)
        sep *= 0.7
    # Visit them nearest first from the first.
    if not out:
        return np.zeros((0, 2))
    left, order = list(range(1, len(out))), [0]
    while left:
        k = min(left, key=lambda i: float(np.sum((out[i] - out[order[-1]]) ** 2)))
        order.append(k)
        left.remove(k)
    return np.array(out)[order]
