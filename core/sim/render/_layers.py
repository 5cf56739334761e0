"""What the renderer prepares once: the static scene's faces, each camera's lens remap and
static layer, and the robot's geometry."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core.errors import ConvergenceError, InvalidInput
from core.geometry.camera import undistort_points
from core.sim._geometry import box_faces
from core.sim.render._camera import CameraModel
from core.sim.render._raster import _shade
from core.sim.render._textures import (
    _board_texture,
    _disc_texture,
    _pyramid,
    _Texture,
    _tile_texture,
)
from core.sim.render.landmarks import scene_landmarks
from core.sim.scene import Board, Robot, Scene, TopMarker

Array = NDArray[np.float64]
Image = NDArray[Any]  # uint8 images; typed loosely because cv2 returns its own array type

# An ideal canvas larger than this many sensors means a broken lens model.
_MAX_CANVAS_SCALE = 3.0

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
    mast_tex: _Texture | None  # the mast marker's disc, in the robot frame
    board_tex: _Texture | None  # in the robot frame
    board_corners: Array | None  # (N, 3) robot frame
    board_poly: Array | None  # (4, 3) robot frame
    board_normal: Array | None  # robot frame


def _robot_geometry(robot: Robot) -> _RobotGeometry:
    mtex, side = None, 0.0
    if robot.marker is not None:
        mtex, side = _disc_in_robot(robot.marker)
    mast = _disc_in_robot(robot.mast_marker)[0] if robot.mast_marker is not None else None
    btex = corners = poly = normal = None
    b = robot.board
    if b is not None and b.enabled:
        t = b.tilt
        # Texture columns along robot +y, rows along the tilted forward axis; face normal
        # (sin t, 0, cos t) looks forward and up, and u x v = -normal (image handedness).
        u = np.array([0.0, 1.0, 0.0])
        v = np.array([math.cos(t), 0.0, -math.sin(t)])
        c = np.array([b.offset[0], b.offset[1], b.mounting_height])
        btex, poly, corners, normal = _board_geometry(b, c, u, v)
    return _RobotGeometry(robot, mtex, side, mast, btex, corners, poly, normal)


def _disc_in_robot(marker: TopMarker) -> tuple[_Texture, float]:
    """Return a marker disc's texture in the robot frame and the side of its square (m)."""
    img, side = _disc_texture(marker)
    n = img.shape[0]
    ts = side / n
    c = np.array([marker.offset[0], marker.offset[1], marker.height])
    o = c + np.array([-side / 2 + ts / 2, -side / 2 + ts / 2, 0.0])
    return _Texture(_pyramid(img), o, np.array([ts, 0.0, 0.0]), np.array([0.0, ts, 0.0])), side


def _board_geometry(
    b: Board, centre: Array, u: Array, v: Array, per_sq: int = 32
) -> tuple[_Texture, Array, Array, Array]:
    """Return a chessboard's texture, outline (4, 3), inner corners (N, 3, row by row, columns
    fastest) and printed-face normal, for a board centred at `centre` whose columns run along
    the unit vector u and rows along v (the face looks along -(u x v))."""
    img = _board_texture(b, per_sq)
    h, w = img.shape[:2]
    ts = b.square_size / per_sq
    W, H = w * ts, h * ts
    corner0 = centre - u * W / 2 - v * H / 2  # texture's outer top-left corner
    tex = _Texture(_pyramid(img), corner0 + (u + v) * ts / 2, u * ts, v * ts)
    poly = np.array([corner0, corner0 + u * W, corner0 + u * W + v * H, corner0 + v * H])
    cols, rows = b.inner_corners
    m = round(b.margin * per_sq) * ts
    jj, ii = np.meshgrid(np.arange(cols), np.arange(rows))
    a = m + (jj.ravel() + 1) * b.square_size
    bb = m + (ii.ravel() + 1) * b.square_size
    corners = corner0 + a[:, None] * u + bb[:, None] * v
    return tex, poly, corners, -np.cross(u, v)


def _in_world(tex: _Texture, R: Array, p: Array) -> _Texture:
    return _Texture(tex.levels, R @ tex.o + p, R @ tex.u, R @ tex.v)


def _landmark_faces(scene: Scene) -> list[_StaticFace]:
    """Return the scene's landmarks as textured faces: each printed page (artwork PNG,
    core.sim.render.landmarks.scene_landmarks) on its mark plane, facing along the mark's +z.

    A page texel (row i, column j) has its centre at ((j + 0.5) / ppm - cx, cy - (i + 0.5) /
    ppm) in the mark frame (x right, y up the page), so texel (s, t) of level 0 lies at
    o + s u + t v with u = R e_x / ppm, v = -R e_y / ppm.
    """
    faces = []
    for lm in scene_landmarks(scene):
        tex = lm.texture
        R, p = lm.T_world_mark[:3, :3], lm.T_world_mark[:3, 3]
        h, w = tex.image.shape[:2]
        cx, cy = tex.centre
        x0, x1, y0, y1 = -cx, w / tex.ppm - cx, cy - h / tex.ppm, cy
        page = np.array([[x0, y1, 0.0], [x1, y1, 0.0], [x1, y0, 0.0], [x0, y0, 0.0]])
        o = R @ np.array([0.5 / tex.ppm - cx, cy - 0.5 / tex.ppm, 0.0]) + p
        u, v = R[:, 0] / tex.ppm, -R[:, 1] / tex.ppm
        texture = _Texture(tex.pyramid, o, u, v)
        faces.append(_StaticFace(page @ R.T + p, R[:, 2].copy(), None, texture, True))
    return faces
