"""Find, locate and read landmarks in a colour image (spec 04 section 4).

* Object marks (blue square frame): the blue score b - max(g, r) is thresholded; a blue
  component with a hole whose outline and hole are quadrilaterals is a frame. Sub-pixel edge
  points are the iso-contour of the blue score at half the frame's contrast (marching squares,
  which is where a symmetric blur leaves a straight step edge), undistorted, assigned to the
  frame's eight edges (corners excluded, where blur rounds them), each fitted by a total
  least-squares line; the eight corners are the lines' intersections. The pose minimises the
  eight corners' reprojection error (the criterion of core.calibration.pose.estimate_plane_pose,
  by Gauss-Newton from the closed-form pose of the outline's homography). Its covariance
  propagates the line fits' residual noise to the corners (first order) and through the
  least-squares pose (sandwich formula, since the corners are correlated). The lines, corners
  and poses of all the frames of an image are computed together (one call for many frames:
  numpy's per-call cost, not arithmetic, is what a frame's pose costs).
* Signposts (red rings): the iso-contours of the red score give up to four concentric circles'
  edges; the outer and the innermost are fitted by ellipses (core.landmarks.conics: algebraic,
  then Sampson refinement).
  The centre's image is the eigenvector of the pencil of two conics (not an ellipse centre, which
  perspective biases); the plane normal has two candidates from the outer conic; the distance
  follows from the known radii. The two-fold ambiguity is resolved by the QR symbol (the
  candidate under which the decoded symbol is square), else by a vertical-wall prior (`up`),
  else by the pencil centre's agreement with each candidate's predicted centre.
* The QR symbol is read on the rectified patch (the mark plane resampled fronto-parallel,
  through the lens model) with zxing-cpp, falling back to cv2.QRCodeDetector; the grey image
  is the per-pixel maximum of the channels, so the blue frame and the red rings read as white.
  Its corners fix the rotation about the normal (x along the symbol's rows); without a decode,
  the three finder patterns' corners are found by comparing the four corner blocks.

One module per part, behind this one: `_view` (the image, its camera and the lens maps),
`_edges` (the patterns' components and sub-pixel edges), `_frames` with `_lines` and
`_plane_pose` (object marks: sides, lines and corners, the plane's pose), `_rings` and
`_ring_pose` (signposts: edge curves and ellipses, the two candidate poses and the decision),
`_symbol` (reading the QR symbol and its rotation), `_detection` (the result).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from itertools import accumulate
from typing import ParamSpec, TypeVar

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix
from core.errors import ConvergenceError, DegenerateConfiguration, InvalidInput
from core.geometry.camera import as_distortion
from core.landmarks._detection import LandmarkDetection
from core.landmarks._edges import holed_components
from core.landmarks._frames import FrameCurves, find_frame_curves, frame_sides, locate_frames
from core.landmarks._ring_pose import locate_signpost, ring_candidates
from core.landmarks._rings import RingCurves, RingFit, ring_curves, ring_edges, ring_fit
from core.landmarks._view import ImageView, undistort_each
from core.landmarks.conics import ConicFit, fit_ellipses

__all__ = ["LandmarkDetection", "detect_landmarks"]


def detect_landmarks(
    image: ArrayLike,
    K: ArrayLike,
    dist: ArrayLike | None = None,
    *,
    frame_size: float = 0.10,
    ring_size: float = 0.20,
    up: ArrayLike | None = None,
    decode: bool = True,
) -> list[LandmarkDetection]:
    """Return every object mark and signpost found in a BGR image, located and (if possible) read.

    image: (H, W, 3) uint8 BGR; K (3, 3), dist (OpenCV k1, k2, p1, p2[, k3]) the camera's
    calibrated intrinsics; frame_size: outer side of the blue frames, ring_size: outer diameter
    of the outer red rings, metres; up: the world's up direction in camera coordinates, when
    known (enables the vertical-wall prior for the rings' ambiguity); decode: read the symbols.
    Raises InvalidInput for a malformed image or camera.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise InvalidInput(
            f"image must be a BGR uint8 array of shape (H, W, 3), got {img.dtype} {img.shape}"
        )
    Km = as_matrix(K, (3, 3), "K")
    if Km[0, 0] <= 0 or Km[1, 1] <= 0 or np.any(Km[2] != [0, 0, 1]) or Km[1, 0] != 0:
        raise InvalidInput(
            "K must be upper triangular with positive focal lengths, K[2] = (0, 0, 1)"
        )
    d = as_distortion(dist)
    for name, v in (("frame_size", frame_size), ("ring_size", ring_size)):
        if not (np.isfinite(v) and 0.005 <= v <= 5.0):
            raise InvalidInput(f"{name} must be 0.005-5 metres, got {v!r}")
    upv = None
    if up is not None:
        upv = as_matrix(up, (3,), "up")
        if np.linalg.norm(upv) < 1e-9:
            raise InvalidInput("up must be a non-zero direction")
        upv = upv / np.linalg.norm(upv)
    # The full-frame passes write into this thread's planes, each reused once it is no longer
    # needed: fresh memory for them at every call (OpenCV's outputs, or numpy's after other
    # allocations, as a camera's frames see them) is faulted in and zeroed by the system, which
    # costs more than the passes themselves (about a thousand faults and a millisecond per
    # 1280 x 720 frame).
    b, g, r, bg, grey = _scratch_planes(img.shape[:2])
    cv2.split(img, [b, g, r])
    cv2.max(b, g, dst=bg)
    cv2.max(bg, r, dst=grey)
    ctx = ImageView(img, grey, Km, d, upv, decode)
    blue = cv2.subtract(b, cv2.max(g, r, dst=g), dst=b)
    red = cv2.subtract(r, bg, dst=r)
    mask = bg  # (free from here: the thresholded scores' scratch plane)
    frame_curves: list[FrameCurves] = []
    # (the frames' polygons only; the rings' ellipse test fits every boundary pixel)
    for outer, hole in holed_components(blue, mask, every_pixel=False):
        fc = _unless_failed(find_frame_curves, blue, outer, hole)
        if fc is not None:
            frame_curves.append(fc)
    frame_edges = [e for e in frame_sides(frame_curves) if e is not None]
    rings: list[RingCurves] = []
    for outer, _hole in holed_components(red, mask):
        edges = _unless_failed(ring_edges, red, outer)
        rc = None if edges is None else ring_curves(edges)
        if rc is not None and rc.matched:  # (else no ring edge to fit)
            rings.append(rc)
    # One undistortion for the frames' edge points and the curves each signpost's pose tries
    # first (its outer and innermost edges: about half its points); the others on demand.
    ideals = undistort_each(
        ctx,
        [e.points for e in frame_edges]
        + [np.concatenate([rc.distorted[k] for k in rc.first_choices()]) for rc in rings],
    )
    frames = [(e, p) for e, p in zip(frame_edges, ideals, strict=False) if p is not None]
    out = locate_frames(ctx, [e for e, _ in frames], [p for _, p in frames], frame_size)
    usable = []
    for rc, p in zip(rings, ideals[len(frame_edges) :], strict=True):
        if p is None:
            continue
        ks = rc.first_choices()
        ends = list(accumulate(len(rc.distorted[k]) for k in ks))
        rc.ideal.update((k, p[e - len(rc.distorted[k]) : e]) for k, e in zip(ks, ends, strict=True))
        usable.append(rc)
    rings = usable
    # The outer and innermost edges' ellipses of all signposts in one batch (the ones the pose
    # needs, when they fit; ring_fit fits the others it falls back to).
    wanted = [(i, k) for i, rc in enumerate(rings) for k in rc.first_choices()]
    try:
        batch = fit_ellipses([rings[i].ideal[k] for i, k in wanted])
    except _FAILED:
        batch = []  # (LAPACK failed on one of them: each ring fits its own below)
    for (i, k), fit in zip(wanted, batch, strict=False):
        rings[i].fits[k] = fit if isinstance(fit, ConicFit) else None
    ring_fits: list[RingFit] = []
    for rc in rings:
        rf = _unless_failed(ring_fit, ctx, rc, ring_size)
        if rf is not None:
            ring_fits.append(rf)
    for rf, cands in zip(ring_fits, ring_candidates(ring_fits, ctx.K), strict=True):
        if cands is None:
            continue
        det = _unless_failed(locate_signpost, ctx, rf, cands, ring_size)
        if det is not None:
            out.append(det)
    return out


P = ParamSpec("P")
Out = TypeVar("Out")

# A candidate whose geometry fails (degenerate fit, distortion not invertible there) is not a
# landmark this detector can locate; it is left out, never returned half-made.
_FAILED = (DegenerateConfiguration, ConvergenceError, np.linalg.LinAlgError)


def _unless_failed(step: Callable[P, Out], *args: P.args, **kwargs: P.kwargs) -> Out | None:
    """Return step(*args, **kwargs) for one candidate, or None where its geometry fails."""
    try:
        return step(*args, **kwargs)
    except _FAILED:
        return None


_SCRATCH = threading.local()


def _scratch_planes(shape: tuple[int, ...]) -> NDArray[np.uint8]:
    """Return this thread's five uint8 planes of `shape` (kept from one call to the next: a
    camera's frames all have the same size; a new size replaces them)."""
    planes: NDArray[np.uint8] | None = getattr(_SCRATCH, "planes", None)
    if planes is None or planes.shape[1:] != shape:
        planes = np.empty((5, *shape), np.uint8)
        _SCRATCH.planes = planes
    return planes
