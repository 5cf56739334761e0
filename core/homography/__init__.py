"""Homographies: estimation, decomposition, the affine homography from image moments."""

from core.homography.estimate import dlt_homography

__all__ = ["dlt_homography"]
