"""Targets in camera images (02 §2): the robot's coloured top marker (`marker`), people by
background subtraction (`background_model`), and a person's body axis fitted to their
silhouette (`body_axis`), the unbiased report of where a person stands."""

from core.localization.detect.background_model import PersonBlobs, PersonDetection, PersonDetector
from core.localization.detect.body_axis import BodyDetection, BodyModel, locate_body_axis
from core.localization.detect.marker import (
    MarkerDetection,
    MarkerDetectorConfig,
    detect_marker,
    marker_ellipse,
    static_marker_mask,
)

__all__ = [
    "BodyDetection",
    "BodyModel",
    "MarkerDetection",
    "MarkerDetectorConfig",
    "PersonBlobs",
    "PersonDetection",
    "PersonDetector",
    "detect_marker",
    "locate_body_axis",
    "marker_ellipse",
    "static_marker_mask",
]
