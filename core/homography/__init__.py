"""Homographies: estimation, decomposition, the affine homography from image moments."""

from core.homography.estimate import (
    HomographyFit,
    check_homography_configuration,
    dlt_homography,
    fit_homography,
    transfer_covariance,
)

__all__ = [
    "HomographyFit",
    "check_homography_configuration",
    "dlt_homography",
    "fit_homography",
    "transfer_covariance",
]
