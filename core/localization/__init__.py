"""Localisation on the floor: estimators, Cramer-Rao bounds and the coverage-and-accuracy map.

Cameras are described by `NetworkCamera`. The estimators (`locate_monocular`,
`triangulate_linear`, `triangulate_on_plane`, `locate_ml`) take pixels (C, B, 2) from C cameras
for B targets and return a `FloorEstimate` with covariances (`locate_groups` locates groups of
single detections, each group on its own plane); `cramer_rao_bound` gives the best
covariance any unbiased estimator can reach; `coverage_map` maps camera count and that bound
over a floor grid, counting only cameras with a clear line of sight past walls and furniture
(`Occluders`); `detect_frame` turns one camera image into the robot's and the people's
detections, the people found by a `PeopleDetector` (`BackgroundPeople` for the twin's cameras,
core.localization.ssd_people.SsdPeopleDetector, a neural detector, for real ones); `Tracker`
follows bodies over time with one asynchronous EKF fed by each camera's detections as they
arrive.
"""

from core.localization.bounds import CramerRaoBound, cramer_rao_bound
from core.localization.boxes import (
    BOX_SIDES,
    DEFAULT_BOX_FIT,
    DEFAULT_BOX_NOISE,
    BoxFit,
    BoxNoise,
    FootMeasurement,
    box_foot,
    cut_mask,
    foot_on_axis,
)
from core.localization.cameras import NetworkCamera
from core.localization.coverage import CoverageMap, coverage_map
from core.localization.detect import BodyDetection, BodyModel, locate_body_axis
from core.localization.detections import (
    BackgroundPeople,
    FrameDetection,
    PeopleDetector,
    detect_frame,
)
from core.localization.ground import (
    FloorEstimate,
    PointStatus,
    locate_ml,
    locate_monocular,
    triangulate_linear,
    triangulate_on_plane,
)
from core.localization.groups import DuplicateView, GroupPositions, locate_groups
from core.localization.occluders import Box, DoorGap, Occluders, Wall, line_of_sight
from core.localization.reorder import ReorderBuffer
from core.localization.tracking import (
    FrameResult,
    Tracker,
    TrackerConfig,
    TrackSnapshot,
    TrackState,
    cv_process_noise,
    cv_transition,
)

__all__ = [
    "BOX_SIDES",
    "DEFAULT_BOX_FIT",
    "DEFAULT_BOX_NOISE",
    "BackgroundPeople",
    "BodyDetection",
    "BodyModel",
    "Box",
    "BoxFit",
    "BoxNoise",
    "CoverageMap",
    "CramerRaoBound",
    "DoorGap",
    "DuplicateView",
    "FloorEstimate",
    "FootMeasurement",
    "FrameDetection",
    "FrameResult",
    "GroupPositions",
    "NetworkCamera",
    "Occluders",
    "PeopleDetector",
    "PointStatus",
    "ReorderBuffer",
    "TrackSnapshot",
    "TrackState",
    "Tracker",
    "TrackerConfig",
    "Wall",
    "box_foot",
    "coverage_map",
    "cramer_rao_bound",
    "cut_mask",
    "cv_process_noise",
    "cv_transition",
    "detect_frame",
    "foot_on_axis",
    "line_of_sight",
    "locate_body_axis",
    "locate_groups",
    "locate_ml",
    "locate_monocular",
    "triangulate_linear",
    "triangulate_on_plane",
]
