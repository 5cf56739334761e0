"""The live 3D scene: a viser server showing the floor plan, every camera's frustum with its
latest image, and the robots and people on the floor with their tracks.

Callers (the API, after a database commit) only record the desired state and wake a worker
thread; the worker redraws what changed. So a call never waits on viser or on a slow client,
bursts of updates to one camera collapse into one redraw, and the scene follows within a few
milliseconds (the contract is "within a second").
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from core.errors import InvalidInput
from server.scene._agents import (
    AgentSpec,
    AgentView,
    agent_id,
    check_image,
    display_image,
    ellipse_2sigma,
    parse_agent,
    parse_covariance,
    parse_track,
)
from server.scene._arm import ArmLayer
from server.scene._entries import CameraEntry, ProjectorEntry, RoomEntry
from server.scene._geometry import (
    Frustum,
    Pose,
    as_polygon,
    frustum_from_intrinsics,
    polygon_centroid,
    pose_from_transform,
    triangulate_polygon,
)
from server.scene._landmarks import LandmarkLayer
from server.scene._navigation import ProjectorView, parse_path, parse_projector

log = logging.getLogger(__name__)

# Colours (RGB). Calibrated cameras stand out in blue; a camera without intrinsics is amber (its
# frustum angle is a guess); a camera without a pose is grey and parked beside the floor plan.
_COLOR_CALIBRATED = (37, 99, 235)
_COLOR_NO_INTRINSICS = (217, 119, 6)
_COLOR_UNPOSED = (148, 150, 160)
_COLOR_WALL = (51, 65, 85)
_ROOM_FILLS = ((191, 219, 254), (187, 247, 208), (254, 215, 170), (233, 213, 255), (254, 202, 202))
# Robots in orange, people in violet (the dashboard's floor page uses the same two colours).
_COLOR_ROBOT = (234, 88, 12)
_COLOR_PERSON = (124, 58, 237)
_COLOR_HEADING = (255, 255, 255)
_COLOR_TRACK = {"robot": (194, 65, 12), "person": (109, 40, 217)}
_COLOR_TRACK_UNKNOWN = (71, 85, 105)
# Tracks float this far (m) above the floor, so the room fills never hide them.
_TRACK_HEIGHT = 0.012
# The planned path in green a little above the tracks; the projector's beam in laser red.
_COLOR_PATH = (22, 163, 74)
_COLOR_BEAM = (220, 38, 38)
_PATH_HEIGHT = 0.016

# Cameras without a pose wait in a row this far (m) outside the floor plan's -Y side, this far
# apart, at this height, looking straight down (camera z = world -Z, camera x = world +X).
_PARK_OFFSET = 1.0
_PARK_SPACING = 0.9
_PARK_HEIGHT = 1.2
_LOOK_DOWN_WXYZ = (0.0, 1.0, 0.0, 0.0)  # half turn about world X
_NO_CAMERA = "(no cameras)"


@dataclass(frozen=True)
class CameraView:
    """How one camera is drawn: scene node, displayed pose, frustum and whether they are known."""

    id: int
    name: str
    node: str
    width: int
    height: int
    has_intrinsics: bool
    has_pose: bool
    pose: Pose
    frustum: Frustum
    label: str


@dataclass(frozen=True)
class RoomView:
    """How one room is drawn: scene node, polygon (m, floor Z = 0) and label."""

    id: int
    name: str
    node: str
    polygon: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class _CameraSpec:
    id: int
    name: str
    width: int
    height: int
    has_intrinsics: bool
    frustum: Frustum
    pose: Pose | None


def _parse_camera(camera: CameraEntry) -> _CameraSpec:
    cam_id, width, height = camera.id, camera.width, camera.height
    T = camera.T_world_camera
    return _CameraSpec(
        id=cam_id,
        name=camera.name or f"camera {cam_id}",
        width=width,
        height=height,
        has_intrinsics=camera.K is not None,
        frustum=frustum_from_intrinsics(camera.K, width, height),
        pose=None if T is None else pose_from_transform(T, f"camera {cam_id} T_world_camera"),
    )


def _parse_rooms(rooms: Sequence[RoomEntry]) -> list[RoomView]:
    out = []
    for room in rooms:
        polygon = as_polygon(room.polygon, f"room {room.id} polygon")
        out.append(
            RoomView(
                id=room.id,
                name=room.name or f"room {room.id}",
                node=f"/floor/rooms/{room.id}",
                polygon=tuple((float(x), float(y)) for x, y in polygon),
            )
        )
    return out


class SceneService(ArmLayer, LandmarkLayer):
    """A viser server drawing the space; every public method is thread-safe and non-blocking.

    State given before `start()` is kept and drawn when the server starts. Updates are applied
    by one worker thread; `flush()` waits until everything asked so far is drawn.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8081,
        *,
        frustum_scale: float = 0.4,
        image_width: int = 320,
        image_interval: float = 0.5,
        verbose: bool = False,
    ) -> None:
        if image_width < 1 or image_interval < 0.0:
            raise InvalidInput(
                f"image_width must be >= 1 and image_interval >= 0, got {image_width}, "
                f"{image_interval}"
            )
        self._host = host
        self._port = port
        self._frustum_scale = frustum_scale
        self._image_width = int(image_width)
        self._image_interval = float(image_interval)
        self._verbose = verbose
        self._server: Any = None  # viser.ViserServer once started
        self._cond = threading.Condition()  # guards the state below; held only briefly
        self._lifecycle = threading.Lock()  # serialises start() and stop()
        self._cameras: dict[int, _CameraSpec] = {}
        self._rooms: list[RoomView] = []
        self._dirty_cameras: set[int] = set()
        self._dirty_floor = True
        self._agents: dict[str, AgentSpec] = {}
        self._tracks: dict[str, np.ndarray] = {}
        self._track_covs: dict[str, np.ndarray] = {}  # covariance of a track's newest point
        self._images: dict[int, np.ndarray] = {}  # newest accepted BGR image per camera
        self._image_times: dict[int, float] = {}  # when it was accepted (time.monotonic)
        self._dirty_agents: set[str] = set()
        self._dirty_tracks: set[str] = set()
        self._dirty_images: set[int] = set()
        self._path = np.zeros((0, 2))  # the planned path, (N, 2) m
        self._projector: ProjectorView | None = None
        self._dirty_navigation = False
        self._busy = False
        self._stopping = False
        self._worker: threading.Thread | None = None
        # What the worker has drawn; read by cameras() / rooms() under _cond.
        self._drawn_cameras: dict[int, CameraView] = {}
        self._drawn_rooms: list[RoomView] = []
        self._drawn_agents: dict[str, AgentView] = {}
        self._drawn_tracks: dict[str, np.ndarray] = {}
        self._drawn_path = np.zeros((0, 2))
        self._drawn_projector: ProjectorView | None = None
        self._init_arms()
        self._init_landmarks()
        self._shown_images: dict[int, np.ndarray] = {}  # RGB, downscaled, as on the frusta
        self._camera_picker: Any = None  # the GUI dropdown, once started
        self.share_requests_refused = 0  # viewers' share-URL requests refused so far

    # -- lifecycle ---------------------------------------------------------------------------

    def start(self) -> None:
        """Start the viser server and the drawing thread (a second call does nothing)."""
        import viser  # imported here: it is heavy, and only a running scene needs it

        with self._lifecycle:
            if self._server is not None:
                return
            # Built outside _cond, so callers recording changes meanwhile are not held up.
            with self._quiet():
                server = viser.ViserServer(host=self._host, port=self._port, verbose=self._verbose)
            server.scene.set_up_direction("+z")
            server.gui.configure_theme(
                show_share_button=False, brand_color=_COLOR_CALIBRATED, control_width="small"
            )
            self._refuse_share_urls(server)
            self._add_gui(server)
            with self._cond:
                self._server = server
                self._port = server.get_port()
                self._stopping = False
                self._dirty_floor = True
                self._dirty_cameras = set(self._cameras)
                self._dirty_agents = set(self._agents)
                self._dirty_tracks = set(self._tracks)
                self._dirty_images = set(self._images)
                self._dirty_navigation = True
                self._restart_arms()
                self._restart_landmarks()
                self._drawn_cameras = {}
                self._drawn_agents = {}
                self._drawn_tracks = {}
                self._worker = threading.Thread(target=self._run, name="scene-worker", daemon=True)
                self._worker.start()
                self._cond.notify_all()

    def _refuse_share_urls(self, server: Any) -> None:
        """Refuse every viewer's request to publish the scene through viser's share service
        (a public tunnel to a third-party host): the scene shows live images of a home."""
        from viser import _messages

        def refuse(client_id: int, _message: object) -> None:
            with self._cond:
                self.share_requests_refused += 1
            log.warning(
                "refused viewer %s's request to publish the 3D scene (share URL)", client_id
            )

        def no_share_url(*_args: object, **_kwargs: object) -> None:
            raise PermissionError("this service never publishes its 3D scene through a share URL")

        websock = server._websock_server
        for message in (_messages.ShareUrlRequest, _messages.ShareUrlDisconnect):
            websock.unregister_handler(message)
        websock.register_handler(_messages.ShareUrlRequest, refuse)
        server.request_share_url = no_share_url

    def stop(self) -> None:
        """Stop the drawing thread and the viser server (safe to call when not started)."""
        with self._lifecycle:
            with self._cond:
                server, worker = self._server, self._worker
                self._stopping = True
                self._cond.notify_all()
            if worker is not None:
                worker.join(timeout=5.0)
            if server is not None:
                with self._quiet():
                    server.stop()
            with self._cond:
                self._server = None
                self._worker = None
                self._camera_picker = None

    @contextlib.contextmanager
    def _quiet(self) -> Iterator[None]:
        """Silence viser's own console banners unless verbose: the service prints the scene's
        address itself, and viser 1.1 prints its panel whatever `verbose` says."""
        if self._verbose:
            yield
            return
        import rich

        console = rich.get_console()
        was_quiet, console.quiet = console.quiet, True
        try:
            yield
        finally:
            console.quiet = was_quiet

    @property
    def running(self) -> bool:
        """Return whether the viser server is up."""
        return self._server is not None

    @property
    def port(self) -> int:
        """Return the viser port (the one actually bound once started)."""
        return self._port

    @property
    def url(self) -> str:
        """Return the viser page's address, http://host:port/."""
        host = "127.0.0.1" if self._host in ("0.0.0.0", "") else self._host
        if ":" in host and not host.startswith("["):
            host = f"[{host}]"
        return f"http://{host}:{self._port}/"

    @property
    def server(self) -> Any:
        """Return the underlying viser.ViserServer (None until started), e.g. to add GUI."""
        return self._server

    # -- state changes (any thread) ----------------------------------------------------------

    def set_floor_plan(self, rooms: Sequence[RoomEntry]) -> None:
        """Replace the floor plan by `rooms` (their polygons [[x, y], ...] m).

        Raises InvalidInput (nothing changes) if a room has a bad polygon.
        """
        parsed = _parse_rooms(rooms)
        with self._cond:
            self._rooms = parsed
            self._dirty_floor = True
            self._cond.notify_all()

    def upsert_camera(self, camera: CameraEntry) -> None:
        """Add or redraw a camera.

        K is 3x3 (pixels) or None; T_world_camera is the 4x4 camera-to-world transform (OpenCV
        camera axes: x right, y down, z forward; world Z up) or None, in which case the camera
        is parked beside the floor plan and labelled "uncalibrated pose".
        Raises InvalidInput (nothing changes) for a malformed K or a T that is not rigid.
        """
        spec = _parse_camera(camera)
        with self._cond:
            self._cameras[spec.id] = spec
            self._dirty_cameras.add(spec.id)
            self._cond.notify_all()

    def remove_camera(self, id: int) -> None:
        """Remove a camera and its image from the scene (nothing happens if it is not there)."""
        with self._cond:
            self._cameras.pop(int(id), None)
            self._images.pop(int(id), None)
            self._image_times.pop(int(id), None)
            self._dirty_cameras.add(int(id))
            self._cond.notify_all()

    def upsert_agent(self, agent: Mapping[str, Any]) -> None:
        """Add or move a robot or a person: {"id", "kind": "robot" | "person", "x", "y",
        "theta", "radius", "height"} (m, rad about +Z from world +X; radius and height default
        by kind). A robot is a cylinder with a heading bar, a person a body with a head.

        Moving an agent only moves its frame; the meshes are rebuilt when its kind or size
        changes. Raises InvalidInput (nothing changes) for a bad id, kind or number.
        """
        spec = parse_agent(agent)
        with self._cond:
            self._agents[spec.id] = spec
            self._dirty_agents.add(spec.id)
            self._cond.notify_all()

    def remove_agent(self, id: str) -> None:
        """Remove an agent and its track (nothing happens if it is not there)."""
        ident = agent_id(id)
        with self._cond:
            self._agents.pop(ident, None)
            self._tracks.pop(ident, None)
            self._track_covs.pop(ident, None)
            self._dirty_agents.add(ident)
            self._dirty_tracks.add(ident)
            self._cond.notify_all()

    def clear_agents(self) -> None:
        """Remove every agent and every track (the space shown changed: they were its)."""
        with self._cond:
            gone = set(self._agents) | set(self._tracks)
            self._agents.clear()
            self._tracks.clear()
            self._track_covs.clear()
            self._dirty_agents |= gone
            self._dirty_tracks |= gone
            self._cond.notify_all()

    def set_track(
        self,
        id: str,
        points: Sequence[Sequence[float]],
        cov: Sequence[Sequence[float]] | None = None,
    ) -> None:
        """Replace a target's track by the poly-line through `points` ([[x, y], ...], m), drawn
        just above the floor; only the newest MAX_TRACK_POINTS are kept, and an empty list
        removes the track. `cov`, the 2x2 covariance (m^2) of the newest point, is drawn as its
        2-sigma ellipse there (a flat translucent disc, true size). Raises InvalidInput
        (nothing changes) for malformed points or a covariance that is not one."""
        ident = agent_id(id)
        track = parse_track(points)
        covariance = None if cov is None else parse_covariance(cov)
        with self._cond:
            if len(track):
                self._tracks[ident] = track
            else:
                self._tracks.pop(ident, None)
            if covariance is not None and len(track):
                self._track_covs[ident] = covariance
            else:
                self._track_covs.pop(ident, None)
            self._dirty_tracks.add(ident)
            self._cond.notify_all()

    def set_planned_path(self, points: Sequence[Sequence[float]]) -> None:
        """Replace the planned path by the poly-line through `points` ([[x, y], ...], world m,
        at least 2), drawn just above the floor; an empty list removes it. Raises InvalidInput
        (nothing changes) for malformed points."""
        path = parse_path(points)
        with self._cond:
            self._path = path
            self._dirty_navigation = True
            self._cond.notify_all()

    def set_projector(self, projector: ProjectorEntry | None) -> None:
        """Show the ceiling projector: its frame with axes at the mount (T_world_projector, the
        pan-tilt base) and, with a spot, its beam from the mount to that floor point; None
        removes it. Raises
        InvalidInput (nothing changes) for a pose that is not rigid or a bad spot."""
        view = None if projector is None else parse_projector(projector)
        with self._cond:
            self._projector = view
            self._dirty_navigation = True
            self._cond.notify_all()

    def set_camera_image(self, camera_id: int, image_bgr: np.ndarray) -> bool:
        """Show `image_bgr` ((H, W, 3) BGR or (H, W) grey, uint8) on the camera's frustum.

        Throttled per camera: an image arriving within `image_interval` seconds of the last one
        accepted is dropped and False is returned (a caller may send every frame). Accepted
        images are downscaled to `image_width` pixels wide by the drawing thread. Raises
        InvalidInput for a bad id or image.
        """
        try:
            cam_id = int(camera_id)
        except (TypeError, ValueError):
            raise InvalidInput(f"camera_id must be an integer, got {camera_id!r}") from None
        now = time.monotonic()
        with self._cond:
            last = self._image_times.get(cam_id)
            if last is not None and now - last < self._image_interval:
                return False
            self._image_times[cam_id] = now  # claimed before the copy: one winner per interval
        try:
            image = check_image(image_bgr)
        except InvalidInput:
            with self._cond:
                if self._image_times.get(cam_id) == now:
                    self._image_times.pop(cam_id)
            raise
        with self._cond:
            self._images[cam_id] = image
            self._dirty_images.add(cam_id)
            self._cond.notify_all()
        return True

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until every change asked so far is drawn; return False on timeout (at once when
        the scene is not started and something is waiting to be drawn)."""
        with self._cond:
            if self._server is None:
                return not self._anything_dirty()
            return self._cond.wait_for(
                lambda: not (self._busy or self._anything_dirty()), timeout=timeout
            )

    def _anything_dirty(self) -> bool:
        return bool(
            self._dirty_cameras
            or self._dirty_floor
            or self._dirty_agents
            or self._dirty_tracks
            or self._dirty_images
            or self._dirty_navigation
            or self._arms_dirty()
            or self._landmarks_dirty()
        )

    # -- what is drawn -----------------------------------------------------------------------

    def cameras(self) -> dict[int, CameraView]:
        """Return the cameras as currently drawn, by id."""
        with self._cond:
            return dict(self._drawn_cameras)

    def rooms(self) -> list[RoomView]:
        """Return the rooms as currently drawn."""
        with self._cond:
            return list(self._drawn_rooms)

    def agents(self) -> dict[str, AgentView]:
        """Return the robots and people as currently drawn, by id."""
        with self._cond:
            return dict(self._drawn_agents)

    def tracks(self) -> dict[str, np.ndarray]:
        """Return the tracks as currently drawn: id -> (N, 2) points (m)."""
        with self._cond:
            return {k: v.copy() for k, v in self._drawn_tracks.items()}

    def planned_path(self) -> np.ndarray:
        """Return the planned path as currently drawn, (N, 2) m (N = 0: none)."""
        with self._cond:
            return self._drawn_path.copy()

    def projector(self) -> ProjectorView | None:
        """Return the projector as currently drawn, or None."""
        with self._cond:
            return self._drawn_projector

    def camera_image(self, camera_id: int) -> np.ndarray | None:
        """Return the RGB image currently shown on a camera's frustum (downscaled), or None."""
        with self._cond:
            image = self._shown_images.get(int(camera_id))
        return None if image is None else image.copy()

    # -- GUI: look through a camera -----------------------------------------------------------

    def _add_gui(self, server: Any) -> None:
        with server.gui.add_folder("Cameras"):
            self._camera_picker = server.gui.add_dropdown(
                "Camera", options=(_NO_CAMERA,), initial_value=_NO_CAMERA
            )
            button = server.gui.add_button("View through camera")
        server.gui.add_markdown(
            "Blue: calibrated camera. Amber: pose without intrinsics. "
            "Grey: uncalibrated pose, parked beside the plan."
        )

        @button.on_click
        def _(event: Any) -> None:
            if event.client is not None:
                self._look_through(event.client, self._camera_picker.value)

    def _look_through(self, client: Any, option: str) -> bool:
        """Put a viewer's camera at the picked camera's pose and field of view."""
        view = self._camera_for_option(option)
        if view is None:
            return False
        with client.atomic():
            client.camera.position = view.pose.position  # before wxyz, which keeps the distance
            client.camera.wxyz = view.pose.wxyz
            client.camera.fov = view.frustum.fov
        return True

    @staticmethod
    def _option_of(view: CameraView) -> str:
        return f"{view.name} (#{view.id})"

    def camera_options(self) -> tuple[str, ...]:
        """Return the entries of the scene's "View through camera" picker, one per camera."""
        with self._cond:
            views = sorted(self._drawn_cameras.values(), key=lambda v: v.id)
        return tuple(self._option_of(v) for v in views)

    def _camera_for_option(self, option: str) -> CameraView | None:
        with self._cond:
            views = list(self._drawn_cameras.values())
        return next((v for v in views if self._option_of(v) == option), None)

    def _refresh_camera_picker(self) -> None:
        picker = self._camera_picker
        if picker is not None:
            picker.options = self.camera_options() or (_NO_CAMERA,)

    # -- drawing (worker thread) -------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stopping or self._anything_dirty())
                if self._stopping:
                    return
                dirty = self._dirty_cameras
                floor_dirty = self._dirty_floor
                self._dirty_cameras, self._dirty_floor = set(), False
                cameras = dict(self._cameras)
                rooms = list(self._rooms)
                moved = {i: self._agents.get(i) for i in self._dirty_agents}
                tracks = {
                    i: (self._tracks.get(i), self._track_covs.get(i)) for i in self._dirty_tracks
                }
                images = {i: self._images.get(i) for i in self._dirty_images}
                self._dirty_agents, self._dirty_tracks, self._dirty_images = set(), set(), set()
                navigation = (self._path, self._projector) if self._dirty_navigation else None
                self._dirty_navigation = False
                arms = self._take_arms()
                landmark_layers = self._take_landmarks()
                self._busy = True
            try:
                self._draw_images(images)  # before the cameras, which may be redrawn with them
                self._draw(dirty, floor_dirty, cameras, rooms)
                self._draw_agents(moved)
                self._draw_arms(*arms)
                self._draw_landmark_layers(*landmark_layers)
                self._draw_tracks(tracks)
                if navigation is not None:
                    self._draw_navigation(*navigation)
            except Exception:  # a drawing bug must not kill the scene for good
                log.exception("redrawing the 3D scene failed")
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()

    def _draw(
        self,
        dirty: set[int],
        floor_dirty: bool,
        cameras: dict[int, _CameraSpec],
        rooms: list[RoomView],
    ) -> None:
        server = self._server
        if server is None:
            return
        drawn = dict(self._drawn_cameras)
        with server.atomic():
            if floor_dirty:
                self._draw_floor(server, rooms)
                with self._cond:
                    self._drawn_rooms = rooms
            # Parked cameras are laid out by id; any change to who is parked, or to the floor
            # plan they sit beside, moves them all.
            parked = sorted(c.id for c in cameras.values() if c.pose is None)
            was_parked = sorted(i for i, v in drawn.items() if not v.has_pose)
            if floor_dirty or parked != was_parked:
                dirty = dirty | set(parked)
            origin = self._park_origin(rooms)
            for cam_id in sorted(dirty):
                spec = cameras.get(cam_id)
                server.scene.remove_by_name(f"/cameras/{cam_id}")
                if spec is None:
                    drawn.pop(cam_id, None)
                    with self._cond:
                        self._shown_images.pop(cam_id, None)
                    continue
                slot = parked.index(cam_id) if spec.pose is None else 0
                drawn[cam_id] = self._draw_camera(server, spec, origin, slot)
        with self._cond:
            self._drawn_cameras = drawn
        if dirty:
            self._refresh_camera_picker()

    def _draw_images(self, images: dict[int, np.ndarray | None]) -> None:
        """Downscale new camera images and put them on the frusta already drawn."""
        server = self._server
        for cam_id, bgr in sorted(images.items()):
            shown = None if bgr is None else display_image(bgr, self._image_width)
            with self._cond:
                if shown is None:
                    self._shown_images.pop(cam_id, None)
                else:
                    self._shown_images[cam_id] = shown
            handle = (
                None
                if server is None
                else server.scene.get_handle_by_name(f"/cameras/{cam_id}/frustum")
            )
            if handle is not None and shown is not None:
                handle.image = shown

    def _draw_agents(self, moved: dict[str, AgentSpec | None]) -> None:
        server = self._server
        if server is None or not moved:
            return
        drawn = dict(self._drawn_agents)
        with server.atomic():
            for ident, spec in sorted(moved.items()):
                node = f"/agents/{ident}"
                old = drawn.get(ident)
                if spec is None:
                    server.scene.remove_by_name(node)
                    drawn.pop(ident, None)
                    continue
                pose = spec.pose
                frame = server.scene.get_handle_by_name(node)
                if (
                    old is not None
                    and frame is not None
                    and old.kind == spec.kind
                    and (
                        old.radius,
                        old.height,
                    )
                    == (spec.radius, spec.height)
                ):
                    frame.position = pose.position  # a move: one small message, no meshes
                    frame.wxyz = pose.wxyz
                else:
                    server.scene.remove_by_name(node)
                    self._draw_agent(server, spec, node)
                drawn[ident] = AgentView(
                    id=spec.id,
                    kind=spec.kind,
                    node=node,
                    pose=pose,
                    radius=spec.radius,
                    height=spec.height,
                )
        with self._cond:
            self._drawn_agents = drawn

    @staticmethod
    def _draw_agent(server: Any, spec: AgentSpec, node: str) -> None:
        pose = spec.pose
        server.scene.add_frame(node, wxyz=pose.wxyz, position=pose.position, show_axes=False)
        r, h = spec.radius, spec.height
        if spec.kind == "robot":
            # Cylinders in viser stand along +Z, centred on their position.
            server.scene.add_cylinder(
                f"{node}/body", radius=r, height=h, color=_COLOR_ROBOT, position=(0.0, 0.0, h / 2)
            )
            # The heading: a bar from the centre to the front rim (agent +X) on the top face.
            server.scene.add_box(
                f"{node}/heading",
                color=_COLOR_HEADING,
                dimensions=(r, 0.25 * r, 0.02),
                position=(r / 2, 0.0, h + 0.01),
            )
        else:
            head = min(0.12, 0.4 * r, 0.1 * h)
            body = max(h - 2.0 * head, 0.01)
            server.scene.add_cylinder(
                f"{node}/body",
                radius=r,
                height=body,
                color=_COLOR_PERSON,
                position=(0.0, 0.0, body / 2),
            )
            server.scene.add_icosphere(
                f"{node}/head", radius=head, color=_COLOR_PERSON, position=(0.0, 0.0, h - head)
            )
        server.scene.add_label(
            f"{node}/label",
            spec.id,
            position=(0.0, 0.0, h + 0.15),
            anchor="bottom-center",
            font_screen_scale=0.8,
        )

    def _draw_navigation(self, path: np.ndarray, projector: ProjectorView | None) -> None:
        server = self._server
        if server is None:
            return
        with server.atomic():
            server.scene.remove_by_name("/navigation/path")
            if len(path) >= 2:
                segments = np.stack([path[:-1], path[1:]], axis=1)  # (N - 1, 2, 2)
                height = np.full((len(segments), 2, 1), _PATH_HEIGHT)
                server.scene.add_line_segments(
                    "/navigation/path",
                    points=np.concatenate([segments, height], axis=2),
                    colors=_COLOR_PATH,
                    thickness=4.0,
                    thickness_units="screen",
                )
            server.scene.remove_by_name("/navigation/projector")
            server.scene.remove_by_name("/navigation/beam")
            if projector is not None:
                pose = projector.pose
                server.scene.add_frame(
                    "/navigation/projector",
                    wxyz=pose.wxyz,
                    position=pose.position,
                    axes_length=0.25,
                    axes_radius=0.012,
                )
                server.scene.add_label(
                    "/navigation/projector/label", projector.name, position=(0.0, 0.0, 0.1)
                )
                if projector.spot is not None:
                    beam = np.array([[pose.position, (*projector.spot, 0.0)]], dtype=np.float64)
                    server.scene.add_line_segments(
                        "/navigation/beam",
                        points=beam,
                        colors=_COLOR_BEAM,
                        thickness=2.0,
                        thickness_units="screen",
                    )
        with self._cond:
            self._drawn_path = path
            self._drawn_projector = projector

    def _draw_tracks(self, tracks: dict[str, tuple[np.ndarray | None, np.ndarray | None]]) -> None:
        server = self._server
        if server is None or not tracks:
            return
        drawn = dict(self._drawn_tracks)
        with self._cond:
            kinds = {i: a.kind for i, a in self._agents.items()}
        with server.atomic():
            for ident, (points, cov) in sorted(tracks.items()):
                node = f"/tracks/{ident}"
                colour = _COLOR_TRACK.get(kinds.get(ident, ""), _COLOR_TRACK_UNKNOWN)
                self._draw_uncertainty(server, ident, points, cov, colour)
                if points is None or len(points) < 2:
                    server.scene.remove_by_name(node)
                    if points is None:
                        drawn.pop(ident, None)
                    else:
                        drawn[ident] = points
                    continue
                segments = np.stack([points[:-1], points[1:]], axis=1)  # (N - 1, 2, 2)
                height = np.full((len(segments), 2, 1), _TRACK_HEIGHT)
                server.scene.add_line_segments(
                    node,
                    points=np.concatenate([segments, height], axis=2),
                    colors=colour,
                    thickness=2.5,
                    thickness_units="screen",
                )
                drawn[ident] = points
        with self._cond:
            self._drawn_tracks = drawn

    @staticmethod
    def _draw_uncertainty(
        server: Any,
        ident: str,
        points: np.ndarray | None,
        cov: np.ndarray | None,
        colour: tuple[int, int, int],
    ) -> None:
        """Draw the 2-sigma ellipse of a track's newest point: a unit disc scaled to the
        semi-axes and turned to the major axis (viser cylinders stand along +Z)."""
        node = f"/uncertainty/{ident}"
        if points is None or not len(points) or cov is None:
            server.scene.remove_by_name(node)
            return
        a, b, angle = ellipse_2sigma(cov)
        x, y = (float(v) for v in points[-1])
        server.scene.add_cylinder(
            node,
            radius=1.0,
            height=0.004,
            color=colour,
            opacity=0.35,
            scale=(max(a, 1e-5), max(b, 1e-5), 1.0),  # a zero scale breaks the mesh normals
            wxyz=(math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)),
            position=(x, y, _TRACK_HEIGHT / 2),
            cast_shadow=False,
            receive_shadow=False,
        )

    @staticmethod
    def _park_origin(rooms: list[RoomView]) -> tuple[float, float]:
        if not rooms:
            return (0.0, -_PARK_OFFSET)
        pts = np.array([p for r in rooms for p in r.polygon])
        return (float(pts[:, 0].min()) + 0.5, float(pts[:, 1].min()) - _PARK_OFFSET)

    def _draw_camera(
        self, server: Any, spec: _CameraSpec, origin: tuple[float, float], slot: int
    ) -> CameraView:
        node = f"/cameras/{spec.id}"
        if spec.pose is None:
            pose = Pose(
                wxyz=_LOOK_DOWN_WXYZ,
                position=(origin[0] + slot * _PARK_SPACING, origin[1], _PARK_HEIGHT),
            )
            color = _COLOR_UNPOSED
            label = f"{spec.name} (uncalibrated pose)"
        else:
            pose = spec.pose
            color = _COLOR_CALIBRATED if spec.has_intrinsics else _COLOR_NO_INTRINSICS
            label = spec.name if spec.has_intrinsics else f"{spec.name} (no intrinsics)"
        server.scene.add_frame(
            node,
            wxyz=pose.wxyz,
            position=pose.position,
            show_axes=spec.pose is not None,
            axes_length=0.6 * self._frustum_scale,
            axes_radius=0.02 * self._frustum_scale,
        )
        server.scene.add_camera_frustum(
            f"{node}/frustum",
            fov=spec.frustum.fov,
            aspect=spec.frustum.aspect,
            scale=self._frustum_scale,
            color=color,
            thickness=2.0,
            thickness_units="screen",
            variant="filled" if spec.pose is not None else "wireframe",
            image=self._shown_images.get(spec.id),
            format="jpeg",
            jpeg_quality=80,
        )
        # Above the frame in camera coordinates is -y (image up).
        server.scene.add_label(
            f"{node}/label",
            label,
            position=(0.0, -0.12, 0.0),
            anchor="bottom-center",
            font_screen_scale=0.9,
        )
        return CameraView(
            id=spec.id,
            name=spec.name,
            node=node,
            width=spec.width,
            height=spec.height,
            has_intrinsics=spec.has_intrinsics,
            has_pose=spec.pose is not None,
            pose=pose,
            frustum=spec.frustum,
            label=label,
        )

    def _draw_floor(self, server: Any, rooms: list[RoomView]) -> None:
        server.scene.remove_by_name("/floor")
        if rooms:
            pts = np.array([p for r in rooms for p in r.polygon])
            lo, hi = pts.min(axis=0) - 1.0, pts.max(axis=0) + 1.0
        else:
            lo, hi = np.array([-5.0, -5.0]), np.array([5.0, 5.0])
        lo, hi = np.floor(lo), np.ceil(hi)
        center = (hi + lo) / 2.0
        size = hi - lo
        server.scene.add_grid(
            "/floor/grid",
            width=float(size[0]),
            height=float(size[1]),
            plane="xy",
            cell_size=0.5,
            section_size=1.0,
            cell_color=(220, 224, 230),
            section_color=(170, 176, 186),
            position=(float(center[0]), float(center[1]), -0.002),
        )
        for i, room in enumerate(rooms):
            poly = np.array(room.polygon)
            n = len(poly)
            ring = np.stack([poly, np.roll(poly, -1, axis=0)], axis=1)  # (N, 2, 2)
            segments = np.concatenate([ring, np.full((n, 2, 1), 0.004)], axis=2)
            server.scene.add_line_segments(
                f"{room.node}/walls",
                points=segments,
                colors=_COLOR_WALL,
                thickness=3.0,
                thickness_units="screen",
            )
            server.scene.add_mesh_simple(
                f"{room.node}/fill",
                vertices=np.concatenate([poly, np.zeros((n, 1))], axis=1),
                faces=triangulate_polygon(poly),
                color=_ROOM_FILLS[i % len(_ROOM_FILLS)],
                flat_shading=True,
                side="double",
                cast_shadow=False,
                receive_shadow=False,
            )
            cx, cy = polygon_centroid(poly)
            server.scene.add_label(
                f"{room.node}/label",
                room.name,
                position=(float(cx), float(cy), 0.02),
                anchor="center-center",
            )
        # Frame the whole plan from a corner, a bit above; clients that connect later use this.
        span = float(max(size.max() - 2.0, 4.0))
        server.initial_camera.look_at = (float(center[0]), float(center[1]), 0.0)
        server.initial_camera.position = (
            float(center[0]) - 0.2 * span,
            float(center[1]) - 0.75 * span,
            0.65 * span,
        )
        server.initial_camera.up = (0.0, 0.0, 1.0)
