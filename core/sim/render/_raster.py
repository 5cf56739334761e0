"""Rasterisation on the ideal (undistorted) canvas: near-plane clipping, textured and filled
polygons and cylinders against a z-buffer."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core.sim.render._textures import _bgr, _Texture

Array = NDArray[np.float64]
Image = NDArray[Any]  # uint8 images; typed loosely because cv2 returns its own array type

_LIGHT = np.array([0.35, 0.55, 1.0]) / np.linalg.norm([0.35, 0.55, 1.0])

# --------------------------------------------------------------------------------------------
# Rasterisation on the ideal canvas


def _clip_near(P: Array, near: float) -> Array | None:
    """Return polygon P (n, 3) (camera frame) clipped to z >= near (Sutherland-Hodgman), or
    None if nothing is left."""
    inside = P[:, 2] >= near
    if inside.all():
        return P
    if not inside.any():
        return None
    out = []
    n = len(P)
    for i in range(n):
        a, b = P[i], P[(i + 1) % n]
        if inside[i]:
            out.append(a)
        if inside[i] != inside[(i + 1) % n]:
            out.append(a + (near - a[2]) / (b[2] - a[2]) * (b - a))
    return np.array(out) if len(out) >= 3 else None


def _clip_segments(A: Array, B: Array, near: float) -> Array:
    """Return the parts of segments A[i]-B[i] (camera frame) in front of z = near, as points."""
    za, zb = A[:, 2], B[:, 2]
    keep = [A[za >= near], B[zb >= near]]
    cross = (za >= near) != (zb >= near)
    if cross.any():
        a, b = A[cross], B[cross]
        f = (near - a[:, 2]) / (b[:, 2] - a[:, 2])
        keep.append(a + f[:, None] * (b - a))
    return np.vstack(keep)


@dataclass
class _Target:
    """A canvas and its z-buffer with the camera that draws on them (world -> canvas)."""

    img: Image
    depth: NDArray[np.float32]
    K: Array
    R: Array  # R_camera_world
    t: Array  # t_camera_world
    near: float

    def __post_init__(self) -> None:
        self.Kinv = np.linalg.inv(self.K)
        self.h, self.w = self.depth.shape

    def to_camera(self, X: Array) -> Array:
        return X @ self.R.T + self.t

    def to_pixels(self, Pc: Array) -> Array:
        p = Pc @ self.K.T
        return p[:, :2] / p[:, 2:3]

    def _roi(self, uv: Array) -> tuple[int, int, int, int] | None:
        x0 = max(0, math.floor(uv[:, 0].min()) - 1)
        y0 = max(0, math.floor(uv[:, 1].min()) - 1)
        x1 = min(self.w, math.ceil(uv[:, 0].max()) + 2)
        y1 = min(self.h, math.ceil(uv[:, 1].max()) + 2)
        if x1 <= x0 or y1 <= y0:
            return None
        return x0, y0, x1, y1

    def _mask(self, uv: Array, roi: tuple[int, int, int, int], convex: bool) -> NDArray[np.bool_]:
        x0, y0, x1, y1 = roi
        m = np.zeros((y1 - y0, x1 - x0), np.uint8)
        pts = np.rint((uv - [x0, y0]) * 16).astype(np.int32)
        if convex:
            cv2.fillConvexPoly(m, pts, 1, cv2.LINE_8, 4)
        else:
            cv2.fillPoly(m, [pts], 1, cv2.LINE_8, 4)
        return m.view(np.bool_)

    def planar(
        self, poly_world: Array, convex: bool = True
    ) -> tuple[tuple[int, int, int, int], NDArray[np.bool_], NDArray[np.float32]] | None:
        """Return (roi, visible mask, plane depth over the roi) of a planar polygon (n, 3)."""
        Pc = self.to_camera(poly_world)
        clipped = _clip_near(Pc, self.near)
        if clipped is None:
            return None
        uv = self.to_pixels(clipped)
        roi = self._roi(uv)
        if roi is None:
            return None
        x0, y0, x1, y1 = roi
        # Newell's normal: robust for any simple polygon, even with collinear vertices.
        n = np.cross(Pc, np.roll(Pc, -1, axis=0)).sum(axis=0)
        if np.linalg.norm(n) < 1e-12:
            return None
        d = float(n @ Pc.mean(axis=0))
        a, b, c = n @ self.Kinv
        us = np.arange(x0, x1, dtype=np.float32)
        vs = np.arange(y0, y1, dtype=np.float32)
        den = np.float32(a) * us[None, :] + np.float32(b * vs[:, None] + c)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (np.float32(d) / den).astype(np.float32)
        mask = self._mask(uv, roi, convex)
        mask &= (z < self.depth[y0:y1, x0:x1]) & (z >= self.near)
        return roi, mask, z

    def fill(
        self, poly_world: Array, bgr: Array, convex: bool = True
    ) -> tuple[tuple[int, int, int, int], NDArray[np.bool_]] | None:
        """Draw a flat-coloured planar polygon (n, 3) world metres; return (roi, mask written)."""
        r = self.planar(poly_world, convex)
        if r is None:
            return None
        (x0, y0, x1, y1), m, z = r
        np.copyto(
            self.img[y0:y1, x0:x1],
            np.clip(np.rint(bgr), 0, 255).astype(np.uint8),
            where=m[..., None],
        )
        np.copyto(self.depth[y0:y1, x0:x1], z, where=m)
        return (x0, y0, x1, y1), m

    def homography(self, o: Array, u: Array, v: Array) -> Array:
        """Return H (3, 3) mapping texel (s, t, 1) on the plane o + s u + t v to canvas pixels."""
        return self.K @ np.stack([self.R @ u, self.R @ v, self.R @ o + self.t], 1)

    def textured(
        self,
        poly_world: Array,
        tex: _Texture,
        *,
        alpha: bool = False,
        convex: bool = True,
        level: int | None = None,
        supersample: int = 1,
    ) -> bool:
        """Draw a textured planar polygon; return whether any pixel was written. The pyramid
        level is chosen so that a texel covers at most one (sub)pixel; with `supersample`
        s > 1 the texture is warped at s times the resolution and box filtered
        (cv2.INTER_AREA), which anti-aliases small, sharp patterns such as a distant board."""
        r = self.planar(poly_world, convex)
        if r is None:
            return False
        (x0, y0, x1, y1), m, z = r
        ss = max(1, int(supersample))
        A = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1.0]])
        H = (
            A
            @ np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1.0]])
            @ self.homography(tex.o, tex.u, tex.v)
        )
        if level is None:
            level = _choose_level(H, tex, poly_world)
        s = float(2**level)
        src = tex.levels[level]
        size = ((x1 - x0) * ss, (y1 - y0) * ss)
        warped = cv2.warpPerspective(
            src,
            H @ np.diag([s, s, 1.0]),
            size,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
        if ss > 1:
            warped = cv2.resize(warped, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        roi_img = self.img[y0:y1, x0:x1]
        if alpha:
            a = warped[..., 3:4].astype(np.float32) / 255.0
            mix = roi_img.astype(np.float32) * (1 - a) + warped[..., :3].astype(np.float32) * a
            m &= a[..., 0] > 0.0
            roi_img[m] = np.rint(mix[m]).astype(np.uint8)
            m &= a[..., 0] >= 0.5
        else:
            np.copyto(roi_img, warped, where=m[..., None])
        np.copyto(self.depth[y0:y1, x0:x1], z, where=m)
        return bool(m.any())

    def cylinder(
        self,
        centre: tuple[float, float],
        z0: float,
        z1: float,
        radius: float,
        side: Array,
        top: Array,
        n: int = 32,
    ) -> None:
        """Draw a vertical cylinder: its convex silhouette in `side`, its top cap in `top`."""
        ang = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
        ring = np.stack([centre[0] + radius * np.cos(ang), centre[1] + radius * np.sin(ang)], 1)
        bot = np.column_stack([ring, np.full(n, z0)])
        topr = np.column_stack([ring, np.full(n, z1)])
        Pb, Pt = self.to_camera(bot), self.to_camera(topr)
        if max(Pb[:, 2].max(), Pt[:, 2].max()) < self.near:
            return
        nxt = np.roll(np.arange(n), -1)
        pts = _clip_segments(np.vstack([Pb, Pt, Pb]), np.vstack([Pb[nxt], Pt[nxt], Pt]), self.near)
        cap = None
        cam_z = float(-(self.R.T @ self.t)[2])
        if cam_z > z1:
            cap = self.fill(topr, top)
        uv = self.to_pixels(pts)
        roi = self._roi(uv)
        if roi is None:
            return
        hull = cv2.convexHull(uv.astype(np.float32))[:, 0, :].astype(np.float64)
        x0, y0, x1, y1 = roi
        # One depth for the whole side: the axis at mid-height (an approximation that only
        # matters where the cylinder nearly touches another surface).
        mid = self.to_camera(np.array([[centre[0], centre[1], (z0 + z1) / 2]]))[0, 2]
        zc = np.float32(max(mid, self.near))
        m = self._mask(hull, roi, True) & (zc < self.depth[y0:y1, x0:x1])
        if cap is not None:
            (cx0, cy0, cx1, cy1), cm = cap
            ix0, iy0, ix1, iy1 = max(x0, cx0), max(y0, cy0), min(x1, cx1), min(y1, cy1)
            if ix1 > ix0 and iy1 > iy0:
                m[iy0 - y0 : iy1 - y0, ix0 - x0 : ix1 - x0] &= ~cm[
                    iy0 - cy0 : iy1 - cy0, ix0 - cx0 : ix1 - cx0
                ]
        self.img[y0:y1, x0:x1][m] = np.clip(np.rint(side), 0, 255).astype(np.uint8)
        self.depth[y0:y1, x0:x1][m] = zc


def _choose_level(H: Array, tex: _Texture, poly_world: Array) -> int:
    # Pixels per level-0 texel at the face's centroid, from the homography's Jacobian.
    c = poly_world.mean(axis=0) - tex.o
    M = np.stack([tex.u, tex.v], 1)
    st = np.linalg.lstsq(M, c, rcond=None)[0]
    p = H @ np.array([[st[0], st[0] + 1, st[0]], [st[1], st[1], st[1] + 1], [1.0, 1.0, 1.0]])
    if np.any(p[2] <= 0):
        return 0
    q = p[:2] / p[2]
    J = np.stack([q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]], 1)
    ppt = math.sqrt(abs(float(np.linalg.det(J))))
    if ppt <= 0:
        return len(tex.levels) - 1
    return int(np.clip(math.floor(math.log2(1.0 / ppt)), 0, len(tex.levels) - 1))


def _shade(rgb: tuple[int, int, int], normal: Array) -> Array:
    return _bgr(rgb) * (0.7 + 0.3 * max(0.0, float(normal @ _LIGHT)))
