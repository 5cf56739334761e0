"""The renderer: each camera's frame of a world state (or of a shown chessboard), with its
ground truth."""

from __future__ import annotations

import copy
import math
from collections import OrderedDict
from typing import Any, TypedDict

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from core.errors import InvalidInput
from core.sim._geometry import yaw_matrix
from core.sim.motion import Pose2D, WorldState
from core.sim.render._camera import CameraModel, Frame, SensorNoise, camera_model
from core.sim.render._drawing import _draw_box, _draw_spot
from core.sim.render._layers import (
    _board_geometry,
    _in_world,
    _landmark_faces,
    _lens_maps,
    _robot_geometry,
    _static_faces,
    _StaticFace,
    _View,
)
from core.sim.render._raster import Array, Image, _Target
from core.sim.render._textures import _bgr, _Texture
from core.sim.render._visibility import _all_seen, _disc_image_centre, _unoccluded
from core.sim.scene import Board, CeilingCamera, Scene, TopMarker

# The radius (m) of the rod that holds the robot's mast marker.
MAST_RADIUS = 0.012

# The default image degradation (frozen: safe to share as a default argument).
_DEFAULT_NOISE = SensorNoise()

# --------------------------------------------------------------------------------------------
# The renderer


class _RobotTruth(TypedDict, total=False):
    marker_world: Array
    marker_pixel: Array
    marker_ellipse_pixel: Array
    marker_visible: bool
    mast_marker_ellipse_pixel: Array
    mast_marker_visible: bool
    board_corners_world: Array
    board_corner_pixels: Array
    board_visible: bool


class Renderer:
    """Renders a scene's cameras; caches each camera's static layer and lens map on first use.

    The static layer holds the floor, walls and furniture and the landmarks' printed pages
    (their artwork, core.sim.render.landmarks.scene_landmarks, on their planes).

    supersample: the static layer is rasterised at this many times the resolution and box
    filtered (anti-aliasing); object_supersample: the same for the textures of moving planar
    objects (marker, board), per frame. near: the near plane in metres.

    The scene's own cameras keep their static layer for good. Any other camera (one that moves,
    such as the eye-in-hand camera) has its layer rasterised on use and kept only among the
    last `moving_views` such cameras, so memory stays bounded however many poses are rendered;
    the lens map of a lens (resolution, intrinsics, distortion) is computed once.
    """

    def __init__(
        self,
        scene: Scene,
        *,
        supersample: int = 2,
        object_supersample: int = 2,
        near: float = 0.05,
        moving_views: int = 4,
    ) -> None:
        if supersample < 1 or object_supersample < 1 or not near > 0 or moving_views < 1:
            raise InvalidInput(
                "supersample, object_supersample and moving_views must be >= 1, near > 0"
            )
        self.scene = scene
        self.supersample = int(supersample)
        self.object_supersample = int(object_supersample)
        self.near = float(near)
        self._faces: list[_StaticFace] | None = None
        self._landmarks: list[_StaticFace] | None = None
        self._views: dict[CeilingCamera, _View] = {}
        self._moving: OrderedDict[CeilingCamera, _View] = OrderedDict()
        self._moving_max = int(moving_views)
        self._lenses: dict[tuple[Any, ...], tuple[Array, Any, Any, int, int]] = {}
        self._empty: dict[str, NDArray[np.uint8]] = {}
        self._robot = _robot_geometry(scene.robot) if scene.robot is not None else None
        self._banks: dict[tuple[float, int], NDArray[np.int16]] = {}

    def for_scene(self, scene: Scene) -> Renderer:
        """Return a renderer of `scene` that shares this one's static layers and lenses: the
        two scenes may differ in their robot only (a raised mast, a mounted board), which is
        drawn per frame. Raises InvalidInput when anything else differs."""
        if scene is self.scene:
            return self
        if scene.model_copy(update={"robot": self.scene.robot}) != self.scene:
            raise InvalidInput("a renderer can be shared only by scenes that differ in the robot")
        other = copy.copy(self)
        other.scene = scene
        other._robot = _robot_geometry(scene.robot) if scene.robot is not None else None
        return other

    def camera(self, camera: str | CeilingCamera) -> CameraModel:
        """Return the CameraModel of a scene camera (by name) or of a given camera."""
        return self._view(camera).camera

    def _view(self, camera: str | CeilingCamera) -> _View:
        cam_spec = self.scene.camera(camera) if isinstance(camera, str) else camera
        view = self._views.get(cam_spec)
        if view is not None:
            return view
        if cam_spec in self.scene.cameras:
            view = self._build_view(cam_spec)
            self._views[cam_spec] = view
            return view
        view = self._moving.get(cam_spec)
        if view is None:
            view = self._build_view(cam_spec)
            self._moving[cam_spec] = view
            while len(self._moving) > self._moving_max:
                self._moving.popitem(last=False)
        else:
            self._moving.move_to_end(cam_spec)
        return view

    def _lens(self, spec: CeilingCamera, cam: CameraModel) -> tuple[Array, Any, Any, int, int]:
        """Return (Kc, map1, map2, canvas width, canvas height) of a camera's lens, cached per
        lens: cameras that differ only in pose share it."""
        key = (spec.resolution, spec.intrinsics, spec.distortion)
        lens = self._lenses.get(key)
        if lens is None:
            if np.any(cam.dist != 0):
                Kc, mx, my = _lens_maps(cam)
                map1, map2 = cv2.convertMaps(mx, my, cv2.CV_16SC2)
                lens = (
                    Kc,
                    map1,
                    map2,
                    math.ceil(float(mx.max())) + 3,
                    math.ceil(float(my.max())) + 3,
                )
            else:
                lens = (cam.K.copy(), None, None, cam.width, cam.height)
            self._lenses[key] = lens
        return lens

    def _build_view(self, spec: CeilingCamera) -> _View:
        cam = camera_model(spec)
        Kc, map1, map2, wc, hc = self._lens(spec, cam)
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
        if self._landmarks is None:
            self._landmarks = _landmark_faces(self.scene)
        for f in self._faces:
            if float(f.normal @ (cam.position - f.poly.mean(0))) <= 1e-9:
                continue
            if f.texture is not None:
                tgt.textured(f.poly, f.texture, convex=f.convex, level=0)
            elif f.colour is not None:
                tgt.fill(f.poly, f.colour, f.convex)
        # Landmarks are printed pages a few millimetres in front of their wall or object: drawn
        # after the static faces, the z-buffer hides them behind walls and furniture; the
        # pyramid level is chosen per page (a ceiling camera sees a 1.7 mm module as ~0.2 px).
        for f in self._landmarks:
            if float(f.normal @ (cam.position - f.poly.mean(0))) <= 1e-9:
                continue
            assert f.texture is not None
            tgt.textured(f.poly, f.texture, convex=True)
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

    def empty(self, camera: str) -> NDArray[np.uint8]:
        """Return the scene camera `camera`'s view of the home with nobody in it and the robot
        away, as an installer records it for a background (cached; sensor noise seed 0)."""
        if camera not in self._empty:
            away = tuple((1e4, 1e4) for _ in self.scene.people)
            self._empty[camera] = self.render(camera, WorldState(0.0, None, away), rng=0).image
        return self._empty[camera]

    def render(
        self,
        camera: str | CeilingCamera,
        state: WorldState,
        *,
        rng: np.random.Generator | int | None = None,
        noise: SensorNoise | None = _DEFAULT_NOISE,
        spot: ArrayLike | None = None,
        exposure: float = 1.0,
    ) -> Frame:
        """Return the Frame that `camera` (a scene camera's name, or any CeilingCamera) sees of
        the scene in `state`. `rng` seeds the sensor noise (same seed, same image); `noise`
        None renders a noiseless, unblurred image. `spot` (3,) world metres: the projector's
        laser spot, drawn where the camera sees it (`_draw_spot`). `exposure` scales the
        scene's light before the spot's is added: a camera set to under-expose (0.5: the floor
        at mid-grey) still sees the laser, far brighter than the room, saturate red."""
        if not (math.isfinite(exposure) and 0.0 < exposure <= 1.0):
            raise InvalidInput(f"exposure must be in (0, 1], got {exposure!r}")
        view = self._view(camera)
        cam = view.camera
        tgt = self._canvas(view)
        if len(state.people) != len(self.scene.people):
            raise InvalidInput(
                f"state has {len(state.people)} people, the scene {len(self.scene.people)}"
            )
        for w, p in zip(self.scene.people, state.people, strict=True):
            body = _bgr(w.colour)
            tgt.cylinder(p, 0.0, w.height, w.radius, body * 0.85, body)
        truth = self._draw_robot(tgt, cam, state.robot)
        if exposure != 1.0:
            tgt.img = cv2.convertScaleAbs(tgt.img, alpha=exposure)
        spot_px, spot_seen = (None, False) if spot is None else _draw_spot(tgt, cam, spot)
        img, gain = self._develop(view, tgt.img, rng, noise)
        return Frame(
            image=img,
            camera=cam,
            time=state.time,
            robot=state.robot,
            people=state.people,
            gain=gain,
            spot_pixel=spot_px,
            spot_visible=spot_seen,
            **truth,
        )

    def render_board(
        self,
        camera: str | CeilingCamera,
        board: Board,
        T_world_board: ArrayLike,
        *,
        rng: np.random.Generator | int | None = None,
        noise: SensorNoise | None = _DEFAULT_NOISE,
        people: tuple[tuple[float, float], ...] = (),
        box: tuple[float, float, float] | None = None,
    ) -> Frame:
        """Return the Frame `camera` sees of a chessboard held at `T_world_board` (4, 4) in
        the room without the robot (an installer showing a printed board to the camera), with
        the walkers at `people` (their floor positions, in the scene's order; none when empty).
        With `box` (x, y, z metres), the board is printed on the top of a box (an object mark):
        the top face, x along the board's columns and y along its rows, is centred on the
        board's centre, and the box extends z behind the printed face.

        The board frame has its origin at the first inner corner, x along the columns, y down
        the rows, z = x cross y into the board (the printed face looks along -z), so the
        inner corners are core.calibration.board_object_points(Chessboard(cols, rows), square)
        mapped by T_world_board. Ground truth: board_corners_world, board_corner_pixels and
        board_visible (all corners in front, inside the image, printed face towards the
        camera and not hidden by the static scene)."""
        T = np.asarray(T_world_board, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InvalidInput(f"T_world_board must be a finite (4, 4) pose, got {T.shape}")
        view = self._view(camera)
        cam = view.camera
        tgt = self._canvas(view)
        if people:
            if len(people) != len(self.scene.people):
                raise InvalidInput(
                    f"{len(people)} people given, the scene has {len(self.scene.people)}"
                )
            for w, q in zip(self.scene.people, people, strict=True):
                body = _bgr(w.colour)
                tgt.cylinder(q, 0.0, w.height, w.radius, body * 0.85, body)
        cols, rows = board.inner_corners
        s = board.square_size
        R, p = T[:3, :3], T[:3, 3]
        centre = p + R @ np.array([(cols - 1) * s / 2, (rows - 1) * s / 2, 0.0])
        tex, poly, corners, normal = _board_geometry(board, centre, R[:, 0], R[:, 1])
        if box is not None:
            _draw_box(tgt, cam.position, centre, R, box)
        px = cam.project(corners)
        front = float(normal @ (cam.position - poly.mean(0))) > 0
        visible = front and _all_seen(cam, tgt, corners)
        if front:
            tgt.textured(poly, tex, supersample=self.object_supersample)
        else:
            tgt.fill(poly, np.array([90.0, 90.0, 90.0]))
        img, gain = self._develop(view, tgt.img, rng, noise)
        return Frame(
            image=img,
            camera=cam,
            time=0.0,
            robot=None,
            people=(),
            board_corners_world=corners,
            board_corner_pixels=px,
            board_visible=visible,
            gain=gain,
        )

    def _canvas(self, view: _View) -> _Target:
        """Return a canvas to draw a frame on: a copy of the view's static layer and its depth."""
        cam = view.camera
        return _Target(
            img=view.static_img.copy(),
            depth=view.static_depth.copy(),
            K=view.Kc,
            R=cam.R_camera_world,
            t=cam.t_camera_world,
            near=self.near,
        )

    def _develop(
        self,
        view: _View,
        ideal: Image,
        rng: np.random.Generator | int | None,
        noise: SensorNoise | None,
    ) -> tuple[Image, float]:
        """Return the sensor image (lens remap, blur, gain, noise) of an ideal canvas and the
        exposure gain it was taken with."""
        img = ideal
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
        return img, gain

    def _draw_disc(
        self, tgt: _Target, cam: CameraModel, tex: _Texture, R: Array, p: Array, m: TopMarker
    ) -> tuple[Array, bool]:
        """Draw a marker disc of the robot at pose (R, p); return its centre (3,) and whether
        the camera sees all of it (centre and rim in front, in the image and unhidden)."""
        centre = R @ np.array([m.offset[0], m.offset[1], m.height]) + p
        # Visibility is decided against the depth buffer before the disc is drawn, so the
        # disc cannot hide itself; the board (drawn later) is checked afterwards.
        ang = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
        rim = centre + m.radius * np.stack([np.cos(ang), np.sin(ang), 0 * ang], 1)
        pts = np.vstack([centre, rim])
        seen = _all_seen(cam, tgt, pts)
        world = _in_world(tex, R, p)
        n = world.levels[0].shape[0]
        o0 = world.o - (world.u + world.v) / 2
        poly = np.array([o0, o0 + world.u * n, o0 + (world.u + world.v) * n, o0 + world.v * n])
        tgt.textured(poly, world, alpha=True, supersample=self.object_supersample)
        return centre, seen

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
        if g.mast_tex is not None and r.mast_marker is not None:
            # The mast (a grey rod from the base's top) and its disc, drawn first: the top
            # marker is then checked against them.
            m = r.mast_marker
            foot = R @ np.array([m.offset[0], m.offset[1], 0.0]) + p
            grey = np.array([120.0, 120.0, 120.0])
            tgt.cylinder(
                (foot[0], foot[1]), r.base_height, m.height - 0.002, MAST_RADIUS, grey, grey
            )
            centre, seen = self._draw_disc(tgt, cam, g.mast_tex, R, p, m)
            truth["mast_marker_ellipse_pixel"] = _disc_image_centre(cam, centre, m.radius)
            truth["mast_marker_visible"] = seen
        if g.marker_tex is not None and r.marker is not None:
            centre, seen = self._draw_disc(tgt, cam, g.marker_tex, R, p, r.marker)
            truth["marker_world"] = centre
            truth["marker_pixel"] = cam.project(centre)[0]
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
            truth["board_visible"] = front and _all_seen(cam, tgt, corners)
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
    noise: SensorNoise | None = _DEFAULT_NOISE,
) -> Frame:
    """Return the Frame `camera` sees of `scene` in `state` (see Renderer.render); the
    scene's static layers are cached between calls."""
    return renderer_for(scene).render(camera, state, rng=rng, noise=noise)
