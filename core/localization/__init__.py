"""Localisation on the floor: estimators, Cramer-Rao bounds and the coverage-and-accuracy map.

Cameras are described by `NetworkCamera`. The estimators (`locate_monocular`,
`triangulate_linear`, `triangulate_on_plane`, `locate_ml`) take pixels (C, B, 2) from C cameras
for B targets and return a `FloorEstimate` with covariances; `cramer_rao_bound` gives the best
covariance any unbiased estimator can reach; `coverage_map` maps camera count and that bound
over a floor grid; `FloorTracker` follows targets over time with Kalman filters and
cross-camera association.
"""

from core.localization.bounds import CramerRaoBound, cramer_rao_bound
from core.localization.cameras import NetworkCamera
from core.localization.coverage import CoverageMap, coverage_map
from core.localization.ground import (
    FloorEstimate,
    PointStatus,
    locate_ml,
    locate_monocular,
    triangulate_linear,
    triangulate_on_plane,
)
from core.localization.tracking import (
    FloorTracker,
    FrameAssociation,
    TrackerConfig,
    TrackPoint,
    TrackSnapshot,
    TrackStatus,
    cv_process_noise,
    cv_transition,
)

__all__ = [
    "CoverageMap",
    "CramerRaoBound",
    "FloorEstimate",
    "FloorTracker",
    "FrameAssociation",
    "NetworkCamera",
    "PointStatus",
    "TrackPoint",
    "TrackSnapshot",
    "TrackStatus",
    "TrackerConfig",
    "coverage_map",
    "cramer_rao_bound",
    "cv_process_noise",
    "cv_transition",
    "locate_ml",
    "locate_monocular",
    "triangulate_linear",
    "triangulate_on_plane",
]
