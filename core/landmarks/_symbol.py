"""A landmark's QR symbol: read on the rectified patch of its mark plane, the rotation about
the normal from its corners or, without a decode, from its finder patterns, and why it was
not read.

The patch is the mark plane resampled fronto-parallel through the lens model; the grey image
is the per-pixel maximum of the channels, so the blue frame and the red rings read as white.
zxing-cpp reads it, cv2.QRCodeDetector where zxing-cpp fails and the modules are large enough.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import zxingcpp
from numpy.typing import NDArray

from core.landmarks._plane_pose import rot_z
from core.landmarks._view import ImageView

Array = NDArray[np.float64]
Image = NDArray[Any]

# Obliquity (deg) beyond which a symbol is not expected to read, and the smallest module
# (pixels) a rectified read can use.
MAX_READ_OBLIQUITY = 75.0
MIN_READ_MODULE_PX = 1.2
# Below this module size (pixels) a read is not tried, and the symbol is reported too small:
# none succeeded in 336 tries of rendered views under 1.2 px (bench_landmarks' camera,
# 0.9-2 m), where each costs a resampling and a failed decoder pass.
MIN_TRY_MODULE_PX = MIN_READ_MODULE_PX
# A nominal symbol (version 4, 33 modules) for the "too small" diagnosis before decoding.
NOMINAL_MODULES = 33
_PATCH_MIN, _PATCH_MAX = 120, 256


@dataclass(frozen=True)
class SymbolRead:
    text: str | None
    corners: Array | None  # (4, 2) mark-plane metres: TL, TR, BR, BL of the symbol
    psi: float | None
    var_psi: float
    squareness: float
    module_px: float


def rectify(
    ctx: ImageView, R: Array, t: Array, half: float, px: int, *, grey: bool = False
) -> Image:
    """Return the mark plane's square [-half, half]^2 resampled fronto-parallel to px x px,
    rows running down the mark's y axis, through the lens model: of the colour image, or with
    `grey` of its per-pixel channel maximum."""
    step = 8
    g = np.arange(0, px + step, step, dtype=np.float64)
    X = -half + (g + 0.5) * 2 * half / px  # along the patch's columns
    Y = half - (g + 0.5) * 2 * half / px  # along its rows
    P = (Y[:, None, None] * R[:, 1] + X[None, :, None] * R[:, 0] + t).reshape(-1, 3)
    uv = ctx.project(P).reshape(len(g), len(g), 2)
    big = (len(g) - 1) * step + 1
    # Both coordinates in one two-channel map (one resize; remap reads it as (x, y) pairs).
    m = cv2.resize(uv.astype(np.float32), (big, big), interpolation=cv2.INTER_LINEAR)[:px, :px]
    src, border = (ctx.grey, 255) if grey else (ctx.image, (255, 255, 255))
    return cv2.remap(  # type: ignore[call-overload]  # (x, y) pairs in one map, none second
        src, m, None, cv2.INTER_LINEAR, borderValue=border
    )


def module_px(ctx: ImageView, R: Array, t: Array, side: float) -> float:
    """Return the image extent (pixels) of `side` metres at the mark centre, along its most
    foreshortened direction."""
    # J = K[:2, :2] (R[:2, :2] z - t[:2] R[2, :2]) / z^2, in plain floats (numpy's per-call
    # cost is most of the time on 2 x 2 matrices).
    (r00, r01, _), (r10, r11, _), (r20, r21, _) = R.tolist()
    tx, ty, z = t.tolist()
    (k00, k01, _), (_, k11, _), _ = ctx.K.tolist()
    m00, m01 = r00 * z - tx * r20, r01 * z - tx * r21
    m10, m11 = r10 * z - ty * r20, r11 * z - ty * r21
    z2 = z * z
    J00, J01 = (k00 * m00 + k01 * m10) / z2, (k00 * m01 + k01 * m11) / z2
    J10, J11 = k11 * m10 / z2, k11 * m11 / z2
    # The smaller singular value of a 2x2 matrix in closed form (the stable root of
    # s^4 - |J|_F^2 s^2 + det(J)^2 = 0: the product of the two over the larger).
    f2 = J00 * J00 + J01 * J01 + J10 * J10 + J11 * J11
    det = J00 * J11 - J01 * J10
    big = f2 + math.sqrt(max(f2 * f2 - 4 * det * det, 0.0))
    return side * math.sqrt(2 * det * det / big) if big > 0 else 0.0


def read_symbol(
    ctx: ImageView,
    R: Array,
    t: Array,
    half: float,
    qr_side: float,
    patch_module_px: float = math.inf,
) -> SymbolRead | None:
    """Return the symbol read on the rectified patch of the square [-half, half]^2 (None when no
    symbol could be read): its text, corners in the mark plane, the rotation psi about the
    normal that puts x along its rows, and how square it is under this pose (RMS distance of
    its corners to the best-fitting square of side qr_side, in units of qr_side). The patch
    has 2.5 pixels per image pixel; from 2-pixel modules on, at most patch_module_px per module
    (at least one pixel per image pixel)."""
    qpx = module_px(ctx, R, t, qr_side)
    if qpx / NOMINAL_MODULES < MIN_TRY_MODULE_PX:
        return None
    # 2.5 patch pixels per image pixel: modules of >= 1.2 px get >= 3 px, what zxing-cpp needs.
    # (The coarser patch only from 2 px modules: below, reads are at the decoder's margin,
    # where any change of the patch turns some views from read to unread and back.)
    module = qpx / NOMINAL_MODULES
    scale = 2.5 if module < 2.0 else max(1.0, min(2.5, patch_module_px / module))
    px = int(min(max(scale * qpx * 2 * half / qr_side, _PATCH_MIN), _PATCH_MAX))
    grey = rectify(ctx, R, t, half, px, grey=True)
    # OpenCV's detector is the fallback where zxing-cpp fails; it is slow (tens of ms) and
    # reads nothing zxing-cpp cannot below 1.5 px modules, so it is not tried there.
    text, pts = _decode(grey, fallback=qpx / NOMINAL_MODULES >= 1.5)
    if text is None or pts is None:
        return None
    # Patch pixels -> mark plane metres.
    P = (pts + 0.5) * 2 * half / px
    P[:, 0] = -half + P[:, 0]
    P[:, 1] = half - P[:, 1]
    fit = square_fit(P)
    if fit is None:
        return None
    return SymbolRead(text, P, fit[0], (1.0 / 33) ** 2, fit[1], qpx)


def square_fit(P: Array) -> tuple[float, float] | None:
    """Return (psi, squareness) of a symbol's corners P (4, 2) (TL, TR, BR, BL) in a mark plane:
    psi the direction of its rows, squareness the RMS residual of the best similarity of a
    square to them, in units of its half side (scale free: the decoder's corners may sit on the
    finder patterns rather than the symbol's edge). None when the corners are not in order."""
    # On four points, plain floats: numpy's per-call cost is most of the time otherwise.
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = P.tolist()
    psi = math.atan2((y1 - y0) + (y2 - y3), (x1 - x0) + (x2 - x3))
    cs, sn = math.cos(psi), math.sin(psi)
    # The square's corners (-1, 1), (1, 1), (1, -1), (-1, -1) turned by psi, and the points
    # about their centroid.
    model = [(-cs - sn, -sn + cs), (cs - sn, sn + cs), (cs + sn, sn - cs), (-cs + sn, -sn - cs)]
    mx, my = (x0 + x1 + x2 + x3) / 4, (y0 + y1 + y2 + y3) / 4
    c = [(x - mx, y - my) for x, y in ((x0, y0), (x1, y1), (x2, y2), (x3, y3))]
    mm = sum(a * a + b * b for a, b in model)
    scale = sum(a * u + b * v for (a, b), (u, v) in zip(c, model, strict=True)) / mm
    if scale <= 0:
        return None
    ss = sum(
        (a - scale * u) ** 2 + (b - scale * v) ** 2 for (a, b), (u, v) in zip(c, model, strict=True)
    )
    return psi, math.sqrt(ss / 4) / scale


_CV_QR = cv2.QRCodeDetector()
_QR_ONLY = zxingcpp.BarcodeFormats(zxingcpp.BarcodeFormat.QRCode)


def _decode(grey: Image, fallback: bool = True) -> tuple[str | None, Array | None]:
    """Return (text, corners (4, 2) TL, TR, BR, BL pixels) of a QR symbol in a grey patch."""
    # The first symbol found is the one used: zxing-cpp stops there (read_barcode), and the
    # rectified patch is neither inverted (light on dark) nor large enough to be downscaled.
    r = zxingcpp.read_barcode(grey, formats=_QR_ONLY, try_invert=False, try_downscale=False)
    if r is not None:
        p = r.position
        pts = np.array(
            [
                [p.top_left.x, p.top_left.y],
                [p.top_right.x, p.top_right.y],
                [p.bottom_right.x, p.bottom_right.y],
                [p.bottom_left.x, p.bottom_left.y],
            ],
            float,
        )
        return r.text, pts
    if not fallback:
        return None, None
    try:
        text, pts, _ = _CV_QR.detectAndDecode(grey)
    except cv2.error:
        return None, None
    if text and pts is not None:
        return text, np.asarray(pts, float).reshape(4, 2)
    return None, None


# The free search of the symbol's axes rectifies a 96 px patch of half side 0.62 qr_side and
# keeps its pixels within 0.71 * 1.02 qr_side of the centre (the symbol's half diagonal and a
# margin): that disc is the same in every patch.
_ANGLE_PATCH_PX = 96
_yy, _xx = np.mgrid[0:_ANGLE_PATCH_PX, 0:_ANGLE_PATCH_PX]
_ANGLE_OUTSIDE = (
    np.hypot(_xx - _ANGLE_PATCH_PX / 2 + 0.5, _yy - _ANGLE_PATCH_PX / 2 + 0.5)
    * 2
    * 0.62
    / _ANGLE_PATCH_PX
    > 0.71 * 1.02
)


def _corner_blocks(px: int) -> NDArray[np.intp]:
    """Return the flat indices (4, (px // 4)^2) into a px x px patch of its four corner blocks,
    block k turned by k quarter turns (np.rot90) so that every block's corner is its first
    pixel: top-left, top-right, bottom-right, bottom-left."""
    b = px // 4
    idx = np.arange(px * px).reshape(px, px)
    blocks = [
        idx[:b, :b],
        np.rot90(idx[:b, -b:], 1),
        np.rot90(idx[-b:, -b:], 2),
        np.rot90(idx[-b:, :b], 3),
    ]
    return np.array(blocks).reshape(4, -1)


# The corner blocks are compared on a patch of this many pixels.
_BLOCKS_PATCH_PX = 96
_CORNER_BLOCKS = _corner_blocks(_BLOCKS_PATCH_PX)


def symbol_angle(ctx: ImageView, R: Array, t: Array, qr_side: float, *, free: bool) -> float | None:
    """Return the rotation psi about the normal that puts x along the symbol's rows, from the
    three finder patterns (no decoding): the symbol's axes from the dark modules' minimum-area
    rectangle (`free`, for the rings) or from the pose's own axes (frames), then the corner
    block least like the other three is the one without a finder (bottom-right). None when the
    modules are too small or the blocks do not single one out."""
    qpx = module_px(ctx, R, t, qr_side)
    if qpx / NOMINAL_MODULES < 0.8:
        return None
    psi0 = 0.0
    if free:
        half = qr_side * 0.62
        px = _ANGLE_PATCH_PX
        grey = cv2.cvtColor(rectify(ctx, R, t, half, px), cv2.COLOR_BGR2GRAY)
        _, dark = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY_INV | cv2.THRESH_OTSU)
        dark[_ANGLE_OUTSIDE] = 0
        if cv2.countNonZero(dark) < 20:
            return None
        # The dark pixels' outer boundaries have the same convex hull as all of them, hence the
        # same minimum-area rectangle, from a tenth of the points.
        contours, _ = cv2.findContours(dark, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        (_, _), (w, h), ang = cv2.minAreaRect(np.concatenate(contours))
        if min(w, h) <= 0 or max(w, h) / min(w, h) > 1.3:
            return None
        # Patch angles run clockwise (y down); the mark plane's counter-clockwise.
        psi0 = -np.radians(ang)
    Rs = R @ rot_z(psi0)
    px = _BLOCKS_PATCH_PX
    grey = cv2.cvtColor(rectify(ctx, Rs, t, qr_side / 2, px), cv2.COLOR_BGR2GRAY)
    # The four corner blocks, each turned so that its corner is the top-left: one gather.
    z = grey.ravel().take(_CORNER_BLOCKS).astype(np.float64)
    z -= z.mean(1, keepdims=True)
    # (np.std's own steps, without its wrapper's calls)
    z /= np.sqrt(np.mean(np.square(z - z.mean(1, keepdims=True)), 1, keepdims=True)) + 1e-9
    C = z @ z.T / z.shape[1]  # the blocks' correlation coefficients
    score = (C.sum(1) - 1) / 3
    k = int(np.argmin(score))
    lowest, second = np.sort(score)[:2]
    if second - lowest < 0.15:
        return None
    # Block k (0 TL, 1 TR, 2 BR, 3 BL in the patch) is the symbol's bottom-right corner.
    return float(psi0 + (2 - k) * np.pi / 2)


def why_unread(ctx: ImageView, R: Array, t: Array, qr_side: float) -> str:
    ray = t / np.linalg.norm(t)
    obliquity = np.degrees(np.arccos(np.clip(-ray @ R[:, 2], -1, 1)))
    if module_px(ctx, R, t, qr_side) / NOMINAL_MODULES < MIN_READ_MODULE_PX:
        return "too small"
    if obliquity > MAX_READ_OBLIQUITY:
        return "too oblique"
    patch = cv2.cvtColor(rectify(ctx, R, t, qr_side / 2, 64), cv2.COLOR_BGR2GRAY)
    lap = cv2.Laplacian(patch, cv2.CV_64F)
    contrast = float(np.percentile(patch, 95) - np.percentile(patch, 5)) + 1e-9
    if float(np.sqrt(np.mean(lap * lap))) / contrast < 0.08:
        return "blurred"
    return "damaged"
