"""Navigation: occupancy grids, path planning, and the laws that follow the projected spot.

* `occupancy_grid(plan, robot_radius, resolution)`: the inflated grid of a floor plan;
  `wall_spans(wall)`: a wall's solid spans between its doors.
* `plan_path(free, start, goal, *, resolution, origin)`: scikit-image's minimum-cost route
  pulled taut by line of sight; `BlockedEndpoint`, `NoRoute` when it cannot.
* Following the projected spot: `StateFeedbackLaw` (Kanayama), `AdaptiveLaw` (Lyapunov-based
  estimate of the spot's velocity), `ProportionalLaw` (the baseline), sharing `SpotTracker`
  and the lost-spot handling of `SpotFollower`.
* `detect_laser_spot(image)`: the spot's sub-pixel centre in an onboard image, or None.
"""

from core.navigation._control import (
    AdaptiveLaw,
    Limits,
    ProportionalLaw,
    Reference,
    SpotFollower,
    SpotTracker,
    StateFeedbackLaw,
    TrackState,
    control_point,
    point_to_unicycle,
)
from core.navigation._grid import FloorPlan, OccupancyGrid, occupancy_grid, wall_spans
from core.navigation._planner import (
    BlockedEndpoint,
    NoRoute,
    plan_path,
    segment_is_free,
)
from core.navigation._spot import SpotDetection, SpotDetectorConfig, detect_laser_spot

__all__ = [
    "AdaptiveLaw",
    "BlockedEndpoint",
    "FloorPlan",
    "Limits",
    "NoRoute",
    "OccupancyGrid",
    "ProportionalLaw",
    "Reference",
    "SpotDetection",
    "SpotDetectorConfig",
    "SpotFollower",
    "SpotTracker",
    "StateFeedbackLaw",
    "TrackState",
    "control_point",
    "detect_laser_spot",
    "occupancy_grid",
    "plan_path",
    "point_to_unicycle",
    "segment_is_free",
    "wall_spans",
]
