"""The twin's cameras: real BGR images of the scene with ground truth.

How a frame is made (per camera):

1. An *ideal* pinhole image (no distortion) is rasterised on a canvas larger than the sensor, so
   that it covers everything the distorted lens sees. Planar faces (floor tiles, walls,
   furniture faces, the robot's top marker, the chessboard) are drawn by warping their textures
   with the plane's homography H = Kc [R u, R v, R o + t] (Hartley & Zisserman eq. 8.1 for a
   world plane), after clipping the face polygon against the near plane z = `near` in camera
   coordinates, so that parts behind the camera cannot wrap around into the image. Visibility
   is a z-buffer: each face's exact per-pixel depth z = d / (n . Kc^-1 (u, v, 1)) for its plane
   n . X = d. Cylinders (the robot base, people) are filled convex silhouettes.
2. The static part (floor, walls, furniture) is rendered once per camera, supersampled and box
   filtered (anti-aliased), with its depth buffer; each frame copies it and draws only what
   moves (people, robot, marker, board) against that depth.
3. Lens distortion by one cv2.remap with a map precomputed per camera: for every distorted
   output pixel, the ideal canvas pixel it sees (the undistortion of that pixel, Newton's method
   in core.geometry.camera.undistort_points).
4. Optical blur (Gaussian), exposure gain and additive Gaussian sensor noise, all seeded.

Pixel coordinates have their origin at the centre of the top-left pixel; colours in images are
BGR (OpenCV), in the scene (r, g, b).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, TypedDict

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import ConvergenceError, InvalidInput
from core.geometry.camera import distort_normalized, project_points, undistort_points
from core.geometry.rotations import matrix_to_rotvec
from core.sim._geometry import box_faces, matrix_to_quaternion, pose_matrix, yaw_matrix
from core.sim.motion import Pose2D, WorldState
from core.sim.scene import Board, CeilingCamera, Robot, Scene, Tiles, TopMarker

Array = NDArray[np.float64]
Image = NDArray[Any]  # uint8 images; typed loosely because cv2 returns its own array type

_LIGHT = np.array([0.35, 0.55, 1.0]) / np.linalg.norm([0.35, 0.55, 1.0])
_MAX_CANVAS_SCALE = 3.0  # an ideal canvas larger than this many sensors means a broken lens model


# --------------------------------------------------------------------------------------------
# Public results and options


@dataclass(frozen=True, eq=False)
class CameraModel:
    """A ceiling camera ready for projection.

    K (3, 3) pixels; dist (5,) OpenCV order (k1, k2, p1, p2, k3); R_world_camera (3, 3) and
    position (3,) metres give the pose T_world_camera (camera frame: x right, y down, z forward).
    """

    name: str
    width: int
    height: int
    K: Array
    dist: Array
    R_world_camera: Array
    position: Array
    frame_rate: float

    @property
    def T_world_camera(self) -> Array:
        """Return the 4x4 pose mapping camera coordinates to world coordinates."""
        T = np.eye(4)
        T[:3, :3] = self.R_world_camera
        T[:3, 3] = self.position
        return T

    @property
    def R_camera_world(self) -> Array:
        """Return the rotation (3, 3) mapping world directions to camera directions."""
        return self.R_world_camera.T

    @property
    def t_camera_world(self) -> Array:
        """Return the translation (3,) of T_camera_world: Xc = R_camera_world X + t."""
        return -self.R_world_camera.T @ self.position

    @property
    def rvec(self) -> Array:
        """Return the rotation vector (3,) of R_camera_world (cv2.projectPoints' rvec)."""
        return matrix_to_rotvec(self.R_camera_world)

    @property
    def quaternion_xyzw(self) -> Array:
        """Return the orientation of T_world_camera as a quaternion (x, y, z, w)."""
        return matrix_to_quaternion(self.R_world_camera)

    def project(self, points: ArrayLike) -> Array:
        """Return the distorted pixels (N, 2) of world points (N, 3) metres."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return project_points(p, self.rvec, self.t_camera_world, self.K, self.dist).points

    def depth(self, points: ArrayLike) -> Array:
        """Return the camera-frame z (N,) metres of world points (N, 3); < 0 is behind."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return (p - self.position) @ self.R_world_camera[:, 2]


def camera_model(camera: CeilingCamera) -> CameraModel:
    """Return the CameraModel of a scene camera."""
    R, pos = pose_matrix(camera.pose)
    return CameraModel(
        name=camera.name,
        width=camera.resolution[0],
        height=camera.resolution[1],
        K=np.array(camera.intrinsics.matrix(), dtype=np.float64),
        dist=np.array(camera.distortion.opencv(), dtype=np.float64),
        R_world_camera=R,
        position=pos,
        frame_rate=camera.frame_rate,
    )


@dataclass(frozen=True)
class SensorNoise:
    """Image degradation, applied after the lens: Gaussian blur of `blur_sigma` pixels, gain
    `gain` (times a per-frame factor 1 + gain_jitter N(0, 1)), then additive Gaussian noise of
    standard deviation `sigma` grey levels, rounded and saturated to 0..255.

    For speed the noise of a frame is a window, at a random offset drawn from the frame's
    generator, into a fixed bank of Gaussian samples held by the renderer; each pixel's noise
    is N(0, sigma^2) (rounded to an integer) and differs between seeds and frames.
    """

    sigma: float = 2.0
    blur_sigma: float = 0.5
    gain: float = 1.0
    gain_jitter: float = 0.0

    def __post_init__(self) -> None:
        for name in ("sigma", "blur_sigma", "gain", "gain_jitter"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InvalidInput(f"SensorNoise.{name} must be finite and >= 0, got {v}")


@dataclass(frozen=True, eq=False)
class Frame:
    """One rendered image with its ground truth (the truth is for tests and scoring only).

    image: (H, W, 3) uint8 BGR. camera: the camera that took it (K, dist, T_world_camera).
    robot: the robot's true pose (None: no robot). people: walkers' floor positions (x, y).
    marker_world (3,) metres: the marker disc's centre; marker_pixel (2,): its projection with
    distortion; marker_ellipse_pixel (2,): the centre of the disc's image ellipse in the ideal
    image (the area centroid of the projected disc, which is not the projection of the disc's
    centre), mapped through the distortion; marker_visible: inside the image, in front of the
    camera and not hidden by the static scene or the board, centre and whole rim.
    board_corners_world (N, 3) and
    board_corner_pixels (N, 2): the chessboard's inner corners, row by row of the board
    (columns fastest); board_visible: all corners in front of the camera, inside the image, on
    the board's front side and unoccluded by the static scene. gain: the exposure gain this
    frame was taken with.
    """

    image: Image
    camera: CameraModel
    time: float
    robot: Pose2D | None
    people: tuple[tuple[float, float], ...]
    marker_world: Array | None = None
    marker_pixel: Array | None = None
    marker_ellipse_pixel: Array | None = None
    marker_visible: bool = False
    board_corners_world: Array | None = None
    board_corner_pixels: Array | None = None
    board_visible: bool = False
    gain: float = field(default=1.0)


# --------------------------------------------------------------------------------------------
# Textures


@dataclass(frozen=True, eq=False)
class _Texture:
    """A texture pyramid on a world plane: texel (s, t) of level 0 sits at o + s u + t v
    (world metres); level l is cv2.pyrDown applied l times, so s_0 = 2^l s_l."""

    levels: tuple[Image, ...]
    o: Array
    u: Array
    v: Array


def _pyramid(img: Image, min_size: int = 8) -> tuple[Image, ...]:
    levels = [img]
    while min(levels[-1].shape[:2]) >= 2 * min_size:
        levels.append(cv2.pyrDown(levels[-1]))
    return tuple(levels)


def _splitmix(x: NDArray[np.uint64]) -> NDArray[np.float64]:
    # A counter-based hash (SplitMix64), uniform in [0, 1): tile colours depend only on the
    # tile's indices and the seed, so tiles continue seamlessly across rooms.
    with np.errstate(over="ignore"):
        z = x + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def _bgr(rgb: tuple[int, int, int]) -> Array:
    return np.array(rgb[::-1], dtype=np.float64)


def _tile_texture(tiles: Tiles, lo: Array, hi: Array, salt: int) -> _Texture:
    """Return the floor texture over the rectangle lo..hi (x, y metres), world-anchored tiles."""
    ppm = tiles.pixels_per_metre
    nx = max(2, math.ceil((hi[0] - lo[0]) * ppm))
    ny = max(2, math.ceil((hi[1] - lo[1]) * ppm))
    x = lo[0] + (np.arange(nx) + 0.5) / ppm
    y = lo[1] + (np.arange(ny) + 0.5) / ppm
    X, Y = np.meshgrid(x, y)
    fx, fy = X / tiles.size, Y / tiles.size
    ti, tj = np.floor(fx), np.floor(fy)
    checker = ((ti + tj) % 2 == 0)[..., None]
    colour = np.where(checker, _bgr(tiles.colour_a), _bgr(tiles.colour_b))
    key = (
        (ti.astype(np.int64) * 73856093)
        ^ (tj.astype(np.int64) * 19349663)
        ^ (tiles.seed * 83492791)
    )
    jitter = 1.0 + tiles.jitter * (2.0 * _splitmix(key.astype(np.uint64)) - 1.0)
    img = colour * jitter[..., None]
    rng = np.random.default_rng([tiles.seed, salt])
    img += rng.normal(0.0, 3.0, size=img.shape)  # fine grain gives texture inside the tiles
    g = tiles.grout_width / 2.0 / tiles.size
    grout = (np.minimum(fx - ti, ti + 1 - fx) < g) | (np.minimum(fy - tj, tj + 1 - fy) < g)
    img[grout] = _bgr(tiles.grout_colour)
    tex = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    o = np.array([lo[0] + 0.5 / ppm, lo[1] + 0.5 / ppm, 0.0])
    return _Texture(_pyramid(tex), o, np.array([1 / ppm, 0.0, 0.0]), np.array([0.0, 1 / ppm, 0.0]))


def _disc_texture(marker: TopMarker, texels: int = 96) -> tuple[Image, float]:
    """Return a BGRA texture (texels x texels) of the disc with area-coverage alpha, and the
    side of the square it covers in metres (the disc's diameter plus a transparent border)."""
    side = 2.0 * marker.radius * 1.25
    ss = 4
    c = (np.arange(texels * ss) + 0.5) / (texels * ss) * side - side / 2
    X, Y = np.meshgrid(c, c)
    inside = (X * X + Y * Y <= marker.radius**2).astype(np.float64)
    alpha = inside.reshape(texels, ss, texels, ss).mean(axis=(1, 3))
    img = np.empty((texels, texels, 4), np.uint8)
    img[..., :3] = _bgr(marker.colour).astype(np.uint8)
    img[..., 3] = np.rint(alpha * 255).astype(np.uint8)
    return img, side


def _board_texture(board: Board, per_square: int = 32) -> Image:
    """Return the chessboard (with its white margin) as a BGR texture, `per_square` texels per
    square; squares are whole texels, so the corners sit exactly on texel boundaries."""
    cols, rows = board.inner_corners
    m = round(board.margin * per_square)
    w, h = (cols + 1) * per_square, (rows + 1) * per_square
    jj, ii = np.meshgrid(np.arange(w) // per_square, np.arange(h) // per_square)
    sq = np.where((ii + jj) % 2 == 0, 20, 235).astype(np.uint8)
    img = np.full((h + 2 * m, w + 2 * m), 235, np.uint8)
    img[m : m + h, m : m + w] = sq
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)


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
        self.img[y0:y1, x0:x1][m] = np.clip(np.rint(bgr), 0, 255).astype(np.uint8)
        self.depth[y0:y1, x0:x1][m] = z[m]
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
            roi_img[m] = warped[m]
        self.depth[y0:y1, x0:x1][m] = z[m]
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


# --------------------------------------------------------------------------------------------
# The static scene


@dataclass(frozen=True, eq=False)
class _StaticFace:
    poly: Array  # (n, 3) world
    normal: Array  # outward normal: faces seen from behind are culled
    colour: Array | None  # BGR, shaded
    texture: _Texture | None
    convex: bool


def _static_faces(scene: Scene) -> list[_StaticFace]:
    """Return the faces of the static scene: textured floors (tiles), flat ceilings, and the
    boxes of walls (split at doors) and furniture with a faint seeded grain."""
    faces: list[_StaticFace] = []
    rng = np.random.default_rng([scene.floor.seed, 0x3A11])
    for k, room in enumerate(scene.rooms):
        poly = np.array(room.polygon, dtype=np.float64)
        tex = _tile_texture(room.floor or scene.floor, poly.min(0), poly.max(0), k)
        up, down = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
        floor = np.column_stack([poly, np.zeros(len(poly))])
        ceiling = np.column_stack([poly, np.full(len(poly), scene.ceiling_height)])
        faces.append(_StaticFace(floor, up, None, tex, False))
        faces.append(_StaticFace(ceiling, down, _shade(scene.ceiling_colour, down), None, False))
    for wall in scene.walls:
        a, b = np.array(wall.start), np.array(wall.end)
        length = float(np.linalg.norm(b - a))
        u = (b - a) / length
        yaw = math.atan2(u[1], u[0])
        half = wall.thickness / 2
        # Solid spans along the wall: full height between doors, lintels above doors.
        spans: list[tuple[float, float, float, float]] = []
        pos = 0.0
        for d in sorted(wall.doors, key=lambda d: d.offset):
            if d.offset > pos:
                spans.append((pos, d.offset, 0.0, wall.height))
            if d.height < wall.height:
                spans.append((d.offset, d.offset + d.width, d.height, wall.height))
            pos = d.offset + d.width
        if pos < length:
            spans.append((pos, length, 0.0, wall.height))
        for s0, s1, z0, z1 in spans:
            # Walls reach half a thickness past their end points so corners close.
            s0e = s0 - half if s0 <= 0 else s0
            s1e = s1 + half if s1 >= length else s1
            centre = a + u * (s0e + s1e) / 2
            for poly, nrm in box_faces(centre, (s1e - s0e, wall.thickness, z1 - z0), yaw, z0):
                tex = _grain_texture(poly, _shade(wall.colour, nrm), rng)
                faces.append(_StaticFace(poly, nrm, None, tex, True))
    for f in scene.furniture:
        for poly, nrm in box_faces(f.centre, f.size, f.yaw):
            tex = _grain_texture(poly, _shade(f.colour, nrm), rng)
            faces.append(_StaticFace(poly, nrm, None, tex, True))
    return faces


def _grain_texture(
    quad: Array, bgr: Array, rng: np.random.Generator, ppm: float = 100.0
) -> _Texture:
    """Return a plaster-like texture for a rectangular face (4, 3) world metres: its shaded
    colour with 3 % seeded grain (blurred over a texel), `ppm` texels per metre."""
    eu, ev = quad[1] - quad[0], quad[3] - quad[0]
    nu = int(np.clip(math.ceil(np.linalg.norm(eu) * ppm), 2, 1024))
    nv = int(np.clip(math.ceil(np.linalg.norm(ev) * ppm), 2, 1024))
    grain = cv2.GaussianBlur(rng.normal(0.0, 0.05, (nv, nu)).astype(np.float32), (0, 0), 1.0)
    img = np.clip(np.rint(bgr[None, None, :] * (1.0 + grain[..., None])), 0, 255)
    u, v = eu / nu, ev / nv
    return _Texture((img.astype(np.uint8),), quad[0] + (u + v) / 2, u, v)


@dataclass(frozen=True, eq=False)
class _View:
    """Per-camera cache: the ideal canvas intrinsics, the static layer and the lens remap."""

    camera: CameraModel
    Kc: Array
    static_img: Image
    static_depth: NDArray[np.float32]
    map1: NDArray[Any] | None  # cv2.convertMaps' fixed-point map (CV_16SC2)
    map2: NDArray[Any] | None


def _lens_maps(cam: CameraModel) -> tuple[Array, NDArray[np.float32], NDArray[np.float32]]:
    """Return (Kc, map_x, map_y): canvas intrinsics and, per distorted pixel, the canvas pixel."""
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height))
    pix = np.stack([u, v], -1).reshape(-1, 2)
    try:
        ideal = undistort_points(pix, cam.K, cam.dist, to_pixels=True)
    except ConvergenceError:
        raise InvalidInput(
            f"camera {cam.name!r}: its distortion is not invertible over the image; "
            "check k1..k3, p1, p2"
        ) from None
    lo = np.floor(ideal.min(0)) - 2
    hi = np.ceil(ideal.max(0)) + 3
    size = hi - lo
    if size[0] > _MAX_CANVAS_SCALE * cam.width or size[1] > _MAX_CANVAS_SCALE * cam.height:
        raise InvalidInput(
            f"camera {cam.name!r}: the distortion spreads the image over {size[0]:.0f} x "
            f"{size[1]:.0f} ideal pixels; the lens model is implausible"
        )
    Kc = cam.K.copy()
    Kc[0, 2] -= lo[0]
    Kc[1, 2] -= lo[1]
    mx = (ideal[:, 0] - lo[0]).reshape(cam.height, cam.width).astype(np.float32)
    my = (ideal[:, 1] - lo[1]).reshape(cam.height, cam.width).astype(np.float32)
    return Kc, mx, my


# --------------------------------------------------------------------------------------------
# The robot


@dataclass(frozen=True, eq=False)
class _RobotGeometry:
    robot: Robot
    marker_tex: _Texture | None  # in the robot frame (o, u, v robot-frame metres)
    marker_side: float
    board_tex: _Texture | None  # in the robot frame
    board_corners: Array | None  # (N, 3) robot frame
    board_poly: Array | None  # (4, 3) robot frame
    board_normal: Array | None  # robot frame


def _robot_geometry(robot: Robot) -> _RobotGeometry:
    mtex, side = None, 0.0
    if robot.marker is not None:
        img, side = _disc_texture(robot.marker)
        n = img.shape[0]
        ts = side / n
        c = np.array([robot.marker.offset[0], robot.marker.offset[1], robot.marker.height])
        o = c + np.array([-side / 2 + ts / 2, -side / 2 + ts / 2, 0.0])
        mtex = _Texture(_pyramid(img), o, np.array([ts, 0.0, 0.0]), np.array([0.0, ts, 0.0]))
    btex = corners = poly = normal = None
    b = robot.board
    if b is not None and b.enabled:
        per_sq = 32
        img = _board_texture(b, per_sq)
        h, w = img.shape[:2]
        ts = b.square_size / per_sq
        t = b.tilt
        # Texture columns along robot +y, rows along the tilted forward axis; face normal
        # (sin t, 0, cos t) looks forward and up, and u x v = -normal (image handedness).
        u = np.array([0.0, 1.0, 0.0])
        v = np.array([math.cos(t), 0.0, -math.sin(t)])
        normal = np.array([math.sin(t), 0.0, math.cos(t)])
        c = np.array([b.offset[0], b.offset[1], b.mounting_height])
        W, H = w * ts, h * ts
        corner0 = c - u * W / 2 - v * H / 2  # texture's outer top-left corner
        btex = _Texture(_pyramid(img), corner0 + (u + v) * ts / 2, u * ts, v * ts)
        poly = np.array([corner0, corner0 + u * W, corner0 + u * W + v * H, corner0 + v * H])
        cols, rows = b.inner_corners
        m = round(b.margin * per_sq) * ts
        jj, ii = np.meshgrid(np.arange(cols), np.arange(rows))
        a = m + (jj.ravel() + 1) * b.square_size
        bb = m + (ii.ravel() + 1) * b.square_size
        corners = corner0 + a[:, None] * u + bb[:, None] * v
    return _RobotGeometry(robot, mtex, side, btex, corners, poly, normal)


def _in_world(tex: _Texture, R: Array, p: Array) -> _Texture:
    return _Texture(tex.levels, R @ tex.o + p, R @ tex.u, R @ tex.v)


# --------------------------------------------------------------------------------------------
# The renderer


class _RobotTruth(TypedDict, total=False):
    marker_world: Array
    marker_pixel: Array
    marker_ellipse_pixel: Array
    marker_visible: bool
    board_corners_world: Array
    board_corner_pixels: Array
    board_visible: bool


class Renderer:
    """Renders a scene's cameras; caches each camera's static layer and lens map on first use.

    supersample: the static layer is rasterised at this many times the resolution and box
    filtered (anti-aliasing); object_supersample: the same for the textures of moving planar
    objects (marker, board), per frame. near: the near plane in metres.
    """

    def __init__(
        self,
        scene: Scene,
        *,
        supersample: int = 2,
        object_supersample: int = 2,
        near: float = 0.05,
    ) -> None:
        if supersample < 1 or object_supersample < 1 or not near > 0:
            raise InvalidInput("supersample and object_supersample must be >= 1, near > 0")
        self.scene = scene
        self.supersample = int(supersample)
        self.object_supersample = int(object_supersample)
        self.near = float(near)
        self._faces: list[_StaticFace] | None = None
        self._views: dict[CeilingCamera, _View] = {}
        self._robot = _robot_geometry(scene.robot) if scene.robot is not None else None
        self._banks: dict[tuple[float, int], NDArray[np.int16]] = {}

    def camera(self, camera: str | CeilingCamera) -> CameraModel:
        """Return the CameraModel of a scene camera (by name) or of a given camera."""
        return self._view(camera).camera

    def _view(self, camera: str | CeilingCamera) -> _View:
        cam_spec = self.scene.camera(camera) if isinstance(camera, str) else camera
        view = self._views.get(cam_spec)
        if view is None:
            view = self._build_view(camera_model(cam_spec))
            self._views[cam_spec] = view
        return view

    def _build_view(self, cam: CameraModel) -> _View:
        if np.any(cam.dist != 0):
            Kc, mx, my = _lens_maps(cam)
            map1, map2 = cv2.convertMaps(mx, my, cv2.CV_16SC2)
            wc = math.ceil(float(mx.max())) + 3
            hc = math.ceil(float(my.max())) + 3
        else:
            Kc, map1, map2 = cam.K.copy(), None, None
            wc, hc = cam.width, cam.height
        s = self.supersample
        A = np.array([[s, 0, (s - 1) / 2], [0, s, (s - 1) / 2], [0, 0, 1.0]])
        bg = _bgr(self.scene.background).astype(np.uint8)
        tgt = _Target(
            img=np.broadcast_to(bg, (hc * s, wc * s, 3)).copy(),
            depth=np.full((hc * s, wc * s), np.inf, np.float32),
            K=A @ Kc,
            R=cam.R_camera_world,
            t=cam.t_camera_world,
            near=self.near,
        )
        if self._faces is None:
            self._faces = _static_faces(self.scene)
        for f in self._faces:
            if float(f.normal @ (cam.position - f.poly.mean(0))) <= 1e-9:
                continue
            if f.texture is not None:
                tgt.textured(f.poly, f.texture, convex=f.convex, level=0)
            elif f.colour is not None:
                tgt.fill(f.poly, f.colour, f.convex)
        if s > 1:
            img = cv2.resize(tgt.img, (wc, hc), interpolation=cv2.INTER_AREA)
            depth = tgt.depth.reshape(hc, s, wc, s).min(axis=(1, 3))
        else:
            img, depth = tgt.img, tgt.depth
        return _View(cam, Kc, img, np.ascontiguousarray(depth), map1, map2)

    def sees(
        self, camera: str | CeilingCamera, points: ArrayLike, tol: float = 0.02
    ) -> NDArray[np.bool_]:
        """Return, for world points (N, 3) metres, whether the camera sees each one: in front,
        inside the image and not hidden by the static scene (walls, furniture) by more than
        `tol` metres of depth."""
        view = self._view(camera)
        cam = view.camera
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        Pc = P @ cam.R_camera_world.T + cam.t_camera_world
        ok = Pc[:, 2] > self.near
        px = cam.project(P)
        ok &= (px[:, 0] >= 0) & (px[:, 0] <= cam.width - 1)
        ok &= (px[:, 1] >= 0) & (px[:, 1] <= cam.height - 1)
        q = np.where(ok[:, None], Pc, [0.0, 0.0, 1.0]) @ view.Kc.T
        uc = np.clip(np.rint(q[:, 0] / q[:, 2]).astype(int), 0, view.static_depth.shape[1] - 1)
        vc = np.clip(np.rint(q[:, 1] / q[:, 2]).astype(int), 0, view.static_depth.shape[0] - 1)
        ok &= Pc[:, 2] <= view.static_depth[vc, uc] + tol
        return ok

    def _noise(self, sigma: float, n: int) -> NDArray[np.int16]:
        bank = self._banks.get((sigma, n))
        if bank is None:
            rng = np.random.default_rng(0x5EED)
            bank = np.rint(rng.standard_normal(2 * n) * sigma).astype(np.int16)
            self._banks[(sigma, n)] = bank
        return bank

    def render(
        self,
        camera: str | CeilingCamera,
        state: WorldState,
        *,
        rng: np.random.Generator | int | None = None,
        noise: SensorNoise | None = SensorNoise(),
    ) -> Frame:
        """Return the Frame that `camera` (a scene camera's name, or any CeilingCamera) sees of
        the scene in `state`. `rng` seeds the sensor noise (same seed, same image); `noise`
        None renders a noiseless, unblurred image."""
        view = self._view(camera)
        cam = view.camera
        tgt = _Target(
            img=view.static_img.copy(),
            depth=view.static_depth.copy(),
            K=view.Kc,
            R=cam.R_camera_world,
            t=cam.t_camera_world,
            near=self.near,
        )
        if len(state.people) != len(self.scene.people):
            raise InvalidInput(
                f"state has {len(state.people)} people, the scene {len(self.scene.people)}"
            )
        for w, p in zip(self.scene.people, state.people, strict=True):
            body = _bgr(w.colour)
            tgt.cylinder(p, 0.0, w.height, w.radius, body * 0.85, body)
        truth = self._draw_robot(tgt, cam, state.robot)

        img = tgt.img
        if view.map1 is not None and view.map2 is not None:
            img = cv2.remap(img, view.map1, view.map2, cv2.INTER_LINEAR)
        gen = np.random.default_rng(rng)
        gain = 1.0
        if noise is not None:
            if noise.blur_sigma > 0:
                img = cv2.GaussianBlur(img, (0, 0), noise.blur_sigma)
            gain = noise.gain * (1.0 + noise.gain_jitter * float(gen.standard_normal()))
            if gain != 1.0:
                img = cv2.convertScaleAbs(img, alpha=max(gain, 0.0))
            if noise.sigma > 0:
                n = img.size
                bank = self._noise(noise.sigma, n)
                off = int(gen.integers(0, n + 1))
                img = cv2.add(img, bank[off : off + n].reshape(img.shape), dtype=cv2.CV_8U)
        return Frame(
            image=img,
            camera=cam,
            time=state.time,
            robot=state.robot,
            people=state.people,
            gain=gain,
            **truth,
        )

    def _draw_robot(self, tgt: _Target, cam: CameraModel, pose: Pose2D | None) -> _RobotTruth:
        g = self._robot
        if g is None or pose is None:
            return _RobotTruth()
        r = g.robot
        R = yaw_matrix(pose.yaw)
        p = np.array([pose.x, pose.y, 0.0])
        tgt.cylinder(
            (pose.x, pose.y), 0.0, r.base_height, r.base_radius, _bgr(r.colour), _bgr(r.top_colour)
        )
        truth = _RobotTruth()
        if g.marker_tex is not None and r.marker is not None:
            centre = R @ np.array([r.marker.offset[0], r.marker.offset[1], r.marker.height]) + p
            px = cam.project(centre)
            # Visibility is decided against the depth buffer before the disc is drawn, so the
            # disc cannot hide itself; the board (drawn later) is checked afterwards.
            ang = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
            rim = centre + r.marker.radius * np.stack([np.cos(ang), np.sin(ang), 0 * ang], 1)
            pts = np.vstack([centre, rim])
            seen = bool(
                np.all(cam.depth(pts) > self.near)
                and np.all(_in_image(cam, cam.project(pts)))
                and np.all(_unoccluded(tgt, pts))
            )
            tex = _in_world(g.marker_tex, R, p)
            n = tex.levels[0].shape[0]
            o0 = tex.o - (tex.u + tex.v) / 2
            poly = np.array([o0, o0 + tex.u * n, o0 + (tex.u + tex.v) * n, o0 + tex.v * n])
            tgt.textured(poly, tex, alpha=True, supersample=self.object_supersample)
            truth["marker_world"] = centre
            truth["marker_pixel"] = px[0]
            truth["marker_ellipse_pixel"] = _disc_image_centre(cam, centre, r.marker.radius)
            truth["marker_visible"] = seen
        if g.board_tex is not None:
            assert g.board_poly is not None and g.board_corners is not None
            assert g.board_normal is not None
            poly = g.board_poly @ R.T + p
            normal = R @ g.board_normal
            corners = g.board_corners @ R.T + p
            px = cam.project(corners)
            front = float(normal @ (cam.position - poly.mean(0))) > 0
            truth["board_visible"] = bool(
                front
                and np.all(cam.depth(corners) > self.near)
                and np.all(_in_image(cam, px))
                and np.all(_unoccluded(tgt, corners))
            )
            if front:
                tgt.textured(
                    poly, _in_world(g.board_tex, R, p), supersample=self.object_supersample
                )
            else:
                tgt.fill(poly, np.array([90.0, 90.0, 90.0]))
            truth["board_corners_world"] = corners
            truth["board_corner_pixels"] = px
            if truth.get("marker_visible"):
                # Hidden by the board if something now lies clearly in front of the disc.
                c = truth["marker_world"][None]
                truth["marker_visible"] = bool(_unoccluded(tgt, c, tol=0.05)[0])
        return truth


def _in_image(cam: CameraModel, px: Array) -> NDArray[np.bool_]:
    """Return whether pixels (N, 2) lie inside the camera's image."""
    return (
        (px[:, 0] >= 0)
        & (px[:, 0] <= cam.width - 1)
        & (px[:, 1] >= 0)
        & (px[:, 1] <= cam.height - 1)
    )


def _unoccluded(tgt: _Target, X: Array, tol: float = 0.0) -> NDArray[np.bool_]:
    """Return whether world points (N, 3) lie in front of tgt's z-buffer (+ tol metres)."""
    Pc = tgt.to_camera(X)
    uv = np.rint(tgt.to_pixels(Pc)).astype(int)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < tgt.w) & (uv[:, 1] >= 0) & (uv[:, 1] < tgt.h)
    uvc = np.clip(uv, 0, [tgt.w - 1, tgt.h - 1])
    return inside & (Pc[:, 2] <= tgt.depth[uvc[:, 1], uvc[:, 0]] + tol)


def _disc_image_centre(cam: CameraModel, centre: Array, radius: float) -> Array:
    """Return the distorted pixel (2,) of the centre of a horizontal disc's image ellipse.

    The disc x^2 + y^2 <= r^2 in its plane maps by H = K [R e1, R e2, R c + t] to the conic
    C' = H^-T diag(1, 1, -r^2) H^-1 (Hartley & Zisserman eq. 2.13), whose centre -A^-1 b (A its
    upper-left 2x2 block, b its last column's top) is the area centroid of the ideal image of
    the disc; it is mapped through the lens distortion like any ideal point.
    """
    H = cam.K @ np.stack(
        [
            cam.R_camera_world[:, 0],
            cam.R_camera_world[:, 1],
            cam.R_camera_world @ centre + cam.t_camera_world,
        ],
        1,
    )
    Hi = np.linalg.inv(H)
    C = Hi.T @ np.diag([1.0, 1.0, -(radius**2)]) @ Hi
    c = -np.linalg.solve(C[:2, :2], C[:2, 2])
    xn = np.linalg.solve(cam.K, np.array([c[0], c[1], 1.0]))
    xd = distort_normalized(xn[:2] / xn[2], cam.dist)
    return (cam.K @ np.array([xd[0], xd[1], 1.0]))[:2]


_RENDERERS: OrderedDict[int, tuple[Scene, Renderer]] = OrderedDict()


def renderer_for(scene: Scene) -> Renderer:
    """Return a cached Renderer of `scene` (the 4 most recently used scenes are kept)."""
    hit = _RENDERERS.get(id(scene))
    if hit is not None and hit[0] is scene:
        _RENDERERS.move_to_end(id(scene))
        return hit[1]
    r = Renderer(scene)
    _RENDERERS[id(scene)] = (scene, r)
    while len(_RENDERERS) > 4:
        _RENDERERS.popitem(last=False)
    return r


def render(
    scene: Scene,
    camera: str | CeilingCamera,
    state: WorldState,
    *,
    rng: np.random.Generator | int | None = None,
    noise: SensorNoise | None = SensorNoise(),
) -> Frame:
    """Return the Frame `camera` sees of `scene` in `state` (see Renderer.render); the
    scene's static layers are cached between calls."""
    return renderer_for(scene).render(camera, state, rng=rng, noise=noise)
