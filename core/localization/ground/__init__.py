"""Locating targets on the floor: monocular, linear, constrained linear and maximum likelihood.

A target (a robot's top marker at height h, a person's foot point at 0) lies on the horizontal
plane Z = h of the world (Z up). Camera k (`NetworkCamera`: Xc = R_k X + t_k, K_k, distortion)
sees it at the pixel u_k. Four estimators of its floor position (X, Y):

* `locate_monocular`: one camera; the back-projected ray meets the plane Z = h.
* `triangulate_linear`: N >= 2 cameras; the 3-D point by linear least squares (the
  inhomogeneous DLT of Hartley & Zisserman, 2nd ed., sec. 12.2), then its (X, Y).
* `triangulate_on_plane`: the same equations with Z = h imposed, unknowns (X, Y) only.
* `locate_ml`: the maximum-likelihood point on the plane, minimising the (whitened) reprojection
  error over (X, Y) with Gauss-Newton / Levenberg-Marquardt from the constrained estimate.

Shapes. `pixels` is (C, B, 2): C cameras, B targets, camera-major, so row k holds what camera k
saw; `visible` (C, B) says which camera saw which target (pixels of unseen entries are ignored
and may be NaN). Without the batch axis, (C, 2) and (C,), one target is located.

Errors. Malformed arrays (shape, NaN where visible, non-positive covariances) raise InvalidInput.
A single target (no batch axis) that cannot be located raises NotEnoughPoints (too few cameras)
or DegenerateConfiguration (a ray parallel to the plane, an ill-conditioned system, a solution
behind a camera). In a batch the bad targets are flagged instead: `status` holds a `PointStatus`
per target, `valid` is `status == OK`, and their estimates are NaN, so one bad detection never
stops a stream.

Pixels are undistorted by Newton's method (core.geometry.camera.undistort_points); a pixel far
outside the image, where the distortion polynomial cannot be inverted, raises ConvergenceError
for the whole call, as detections come from inside the image.

Uncertainty. Every estimate carries the first-order covariance of *that* estimator given the
pixel covariances (isotropic `pixel_sigma`, or per-detection `pixel_cov`): for the closed-form
estimators the exact linearisation of the estimator, for ML the inverse Fisher information at
the estimate, which is the Cramer-Rao bound (core.localization.bounds) evaluated there.
"""

from core.localization.ground._estimate import FloorEstimate, Method, PointStatus
from core.localization.ground._linear import triangulate_linear, triangulate_on_plane
from core.localization.ground._maximum_likelihood import locate_ml
from core.localization.ground._monocular import locate_monocular

__all__ = [
    "FloorEstimate",
    "Method",
    "PointStatus",
    "locate_ml",
    "locate_monocular",
    "triangulate_linear",
    "triangulate_on_plane",
]
