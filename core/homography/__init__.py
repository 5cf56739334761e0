"""Homographies: estimation, decomposition, the affine homography from image moments."""

from core.homography.decompose import (
    CASE_ALONG_NORMAL,
    CASE_GENERAL,
    CASE_PURE_ROTATION,
    CASE_SINGULAR,
    HomographyDecompositionBatch,
    PlaneMotion,
    decompose_homography,
    decompose_homography_batch,
)
from core.homography.dlt import dlt_homography
from core.homography.estimate import HomographyFit, fit_homography, transfer_covariance
from core.homography.moments import (
    MomentAffine,
    Moments,
    affine_from_moments,
    estimate_affine_from_moments,
    homogeneous_moments,
    image_moments,
    mask_moments,
    point_moments,
    polygon_moments,
    transform_moments,
)
from core.homography.normalization import check_homography_configuration

__all__ = [
    "CASE_ALONG_NORMAL",
    "CASE_GENERAL",
    "CASE_PURE_ROTATION",
    "CASE_SINGULAR",
    "HomographyDecompositionBatch",
    "HomographyFit",
    "MomentAffine",
    "Moments",
    "PlaneMotion",
    "affine_from_moments",
    "check_homography_configuration",
    "decompose_homography",
    "decompose_homography_batch",
    "dlt_homography",
    "estimate_affine_from_moments",
    "fit_homography",
    "homogeneous_moments",
    "image_moments",
    "mask_moments",
    "point_moments",
    "polygon_moments",
    "transfer_covariance",
    "transform_moments",
]
