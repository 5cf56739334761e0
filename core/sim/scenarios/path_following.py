"""The `path-following` scenario of the twin (spec 03).

A tour of the living room (about 10 m, `TOUR`) planned leg by leg on the inflated floor plan
(`plan_tour`, core.navigation.plan_path), drawn by the projector at 0.3 m/s
(core.projector.project_path, with the projector's calibrated model: the `projector-calibration`
scenario's), and followed by the robot with each of the three laws on the same path, the same
slip and the same camera noise (one seed): the floor camera at 15 Hz with 100 ms latency and
pixel noise, the spot back-projected on the floor plane from the camera's own one-view
calibration (core.sim.spot_following, core.sim.floor_camera). The twin's true projector
(core.sim.projector) draws the spot. Errors are the distance between the robot's control point
and the true spot, against the twin.

What is measured: the floor camera's frames are rendered from the robot's true pose (the home,
and the spot's red light where the camera sees it: core.sim.render), 15 a second, and the spot
is found in each by core.navigation.detect_laser_spot (no laser-off frame: the camera moves),
then given SPOT_PIXEL_SIGMA of extra pixel noise and dropped at random (DETECTION_PROBABILITY,
glints and motion blur the renderer does not draw). The floor camera's intrinsics come from its
own Zhang calibration on rendered chessboard views (`floor_camera_intrinsics`,
core.sim.intrinsics), its plane from one rendered view of a floor chessboard on those
intrinsics (`calibrate_floor_camera`): no estimator reads the true lens (FLOOR_CAMERA_K,
FLOOR_CAMERA_DIST), which only forms the images. Without a renderer (unit tests)
the spot's true projection stands in for the detection.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from shapely.geometry import LineString

from core.errors import InvalidInput
from core.localization import NetworkCamera
from core.navigation import occupancy_grid, plan_path
from core.navigation._control import Limits
from core.projector import PanTiltProjector, project_path
from core.sim.floor_camera import (
    FLOOR_CAMERA_K,
    calibrate_floor_camera,
    floor_camera_intrinsics,
    floor_camera_mount,
)
from core.sim.intrinsics import focal_error_pct
from core.sim.projector import twin_projector
from core.sim.render import Renderer
from core.sim.scenarios.projector_calibration import projector_calibration
from core.sim.scene import Scene, default_scene
from core.sim.spot_following import (
    CAMERA_LATENCY,
    CAMERA_RATE,
    CONTROL_DT,
    CORNER_RADIUS,
    PLAN_MARGIN,
    PLAN_RESOLUTION,
    SPOT_ACCELERATION,
    SPOT_PIXEL_SIGMA,
    SPOT_SPEED,
    make_laws,
    simulate_following,
    start_pose,
)

Array = NDArray[np.float64]

# The living-room tour the spot draws (world x, y metres), planned leg by leg.
TOUR = ((1.6, 1.2), (3.6, 1.2), (3.6, 5.3), (2.9, 5.3), (2.9, 3.6), (0.8, 3.45))
PLAN_SIMPLIFY = 0.03


def plan_tour(scene: Scene, waypoints: tuple[tuple[float, float], ...] = TOUR) -> Array:
    """Return the planned tour (N, 2): each leg between consecutive waypoints planned on the
    floor plan inflated by the robot's radius plus a margin, the legs joined."""
    radius = (scene.robot.base_radius if scene.robot else 0.2) + PLAN_MARGIN
    grid = occupancy_grid(scene, radius, PLAN_RESOLUTION)
    legs = [
        plan_path(grid.free, a, b, resolution=grid.resolution, origin=grid.origin)
        for a, b in itertools.pairwise(waypoints)
    ]
    path = np.vstack([legs[0]] + [leg[1:] for leg in legs[1:]])
    # The taut path hugs the inflated furniture's rounded corners in cell-sized steps; merge
    # them (Douglas-Peucker within PLAN_SIMPLIFY, less than the planning margin) so the spot
    # sweeps round them in one fillet.
    simple = LineString(path).simplify(PLAN_SIMPLIFY, preserve_topology=False)
    return np.asarray(simple.coords, dtype=np.float64)


@dataclass(frozen=True)
class LawMetrics:
    """One law's errors (m): RMS over the run, max, steady (RMS on straight cruising after
    3 s), time to finish (s), spot-lost events."""

    rms_m: float
    max_m: float
    steady_m: float
    finish_s: float | None
    lost_events: int


@dataclass(frozen=True)
class PathFollowingResult:
    """Metrics of `path-following`: path length (m), spot speed (m/s), camera rate (Hz) and
    latency (s), pixel noise (px), the projector's drawing error (max distance of the drawn
    spot from the planned path, m, from the calibrated model's residual error), the floor
    camera's plane errors (normal deg, distance m), where the floor camera's images came from
    (`source`: "rendered" or "projected"), per-law metrics and the error series (`series`:
    law -> {"t": [...], "error_m": [...]}, decimated to 5 Hz for plots)."""

    scenario: str
    seed: int
    path_length_m: float
    spot_speed_mps: float
    camera_hz: float
    latency_s: float
    pixel_sigma: float
    drawing_error_max_m: float
    floor_normal_error_deg: float
    floor_distance_error_m: float
    floor_camera_intrinsics_from: str
    floor_camera_focal_error_pct: float
    floor_camera_rms_px: float
    source: str
    laws: dict[str, LawMetrics]
    series: dict[str, dict[str, list[float]]] = field(repr=False)

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


def path_following(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    cameras: list[NetworkCamera] | None = None,
    tour: tuple[tuple[float, float], ...] = TOUR,
    projector: PanTiltProjector | None = None,
    rendered: bool = True,
) -> PathFollowingResult:
    """Run the `path-following` scenario (module docstring) and return its metrics.

    The projector is first calibrated as in `projector-calibration` (with `cameras`, default
    the network calibration's) unless a `projector` model is given; `tour` the waypoints the
    path is planned through. `rendered` (the default): the floor camera's calibration view and
    every frame it takes while following are rendered and detected; otherwise true projections
    plus noise stand in for them.
    """
    scene = scene or default_scene()
    robot = scene.robot
    if robot is None:
        raise InvalidInput(f"scene {scene.name!r} has no robot")
    truth = twin_projector(scene, seed)
    model = projector or projector_calibration(scene, seed, cameras=cameras).model
    path = plan_tour(scene, tour)
    traj = project_path(
        model,
        path,
        SPOT_SPEED,
        spot_acceleration=SPOT_ACCELERATION,
        corner_radius=CORNER_RADIUS,
    )
    drawn = truth.spot(traj.q)
    drawing_error = float(np.max(np.linalg.norm(drawn - traj.spot, axis=1)))
    renderer = Renderer(scene, supersample=1) if rendered else None
    intrinsics = floor_camera_intrinsics(np.random.default_rng([seed, 8]))
    plane = calibrate_floor_camera(np.random.default_rng([seed, 7]), renderer, intrinsics)
    true_plane = np.linalg.inv(floor_camera_mount())
    n_true = true_plane[:3, 2]
    d_true = float(n_true @ true_plane[:3, 3])
    if d_true < 0:
        n_true, d_true = -n_true, -d_true
    normal_err = math.degrees(math.acos(min(1.0, float(plane.normal @ n_true))))
    limits = Limits(robot.limits.max_speed, robot.limits.max_turn_rate)
    start = start_pose(traj)
    laws: dict[str, LawMetrics] = {}
    series: dict[str, dict[str, list[float]]] = {}
    for law in make_laws(limits):
        run = simulate_following(law, traj, truth, plane, start, scene, seed, renderer=renderer)
        laws[law.name] = LawMetrics(
            rms_m=run.rms,
            max_m=float(run.error.max()),
            steady_m=run.steady,
            finish_s=run.finished_s,
            lost_events=run.lost_events,
        )
        step = max(1, round(0.2 / CONTROL_DT))
        series[law.name] = {
            "t": [round(float(x), 3) for x in run.time[::step]],
            "error_m": [round(float(x), 5) for x in run.error[::step]],
        }
    return PathFollowingResult(
        scenario="path-following",
        seed=seed,
        path_length_m=traj.length,
        spot_speed_mps=SPOT_SPEED,
        camera_hz=CAMERA_RATE,
        latency_s=CAMERA_LATENCY,
        pixel_sigma=SPOT_PIXEL_SIGMA,
        drawing_error_max_m=drawing_error,
        floor_normal_error_deg=normal_err,
        floor_distance_error_m=abs(plane.distance - d_true),
        floor_camera_intrinsics_from=intrinsics.source,
        floor_camera_focal_error_pct=focal_error_pct(intrinsics.K, FLOOR_CAMERA_K),
        floor_camera_rms_px=intrinsics.rms,
        source="rendered" if rendered else "projected",
        laws=laws,
        series=series,
    )
