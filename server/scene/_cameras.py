"""The cameras in the live scene: each camera's frustum at its pose with its latest image, and
the "View through camera" picker that puts a viewer's eye where a camera is.

A camera whose intrinsics are unknown is drawn with a guessed field of view, in amber; one
without a pose is parked, grey, in a row beside the floor plan. Images are checked and
throttled in the caller's thread, and downscaled by the drawing thread.

`CameraLayer` is the part of SceneService that holds and draws cameras; it uses the service's
lock (`_cond`) and viser server (`_server`).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from server.scene._entries import CameraEntry
from server.scene._floor import RoomView
from server.scene._geometry import Frustum, Pose, frustum_from_intrinsics, pose_from_transform

# Colours (RGB). Calibrated cameras stand out in blue; a camera without intrinsics is amber (its
# frustum angle is a guess); a camera without a pose is grey and parked beside the floor plan.
COLOR_CALIBRATED = (37, 99, 235)
_COLOR_NO_INTRINSICS = (217, 119, 6)
_COLOR_UNPOSED = (148, 150, 160)

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
class CameraSpec:
    """A camera as asked for: its frustum, and its pose when it has one."""

    id: int
    name: str
    width: int
    height: int
    has_intrinsics: bool
    frustum: Frustum
    pose: Pose | None


def parse_camera(camera: CameraEntry) -> CameraSpec:
    """Return the checked camera; raise InvalidInput for a malformed K or a T that is not rigid."""
    cam_id, width, height = camera.id, camera.width, camera.height
    T = camera.T_world_camera
    return CameraSpec(
        id=cam_id,
        name=camera.name or f"camera {cam_id}",
        width=width,
        height=height,
        has_intrinsics=camera.K is not None,
        frustum=frustum_from_intrinsics(camera.K, width, height),
        pose=None if T is None else pose_from_transform(T, f"camera {cam_id} T_world_camera"),
    )


def check_image(image: Any) -> NDArray[np.uint8]:
    """Return a copy of a BGR (H, W, 3) or grey (H, W) uint8 image; raise InvalidInput if not."""
    if not isinstance(image, np.ndarray):
        raise InvalidInput(f"a camera image must be a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise InvalidInput(f"a camera image must be uint8, got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise InvalidInput(
            f"a camera image must be (H, W, 3) BGR or (H, W) grey, got shape {image.shape}"
        )
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise InvalidInput(f"a camera image must not be empty, got {image.shape}")
    return image.copy()


def display_image(image_bgr: NDArray[np.uint8], max_width: int) -> NDArray[np.uint8]:
    """Return the RGB image shown on a frustum: at most `max_width` wide (area averaging)."""
    import cv2

    img = image_bgr if image_bgr.ndim == 3 else cv2.cvtColor(image_bgr, cv2.COLOR_GRAY2BGR)
    h, w = img.shape[:2]
    if w > max_width:
        size = (max_width, max(1, round(h * max_width / w)))
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img[:, :, ::-1])


class CameraLayer:
    """The cameras of SceneService: thread-safe state changes, drawing on the scene's worker."""

    _cond: threading.Condition
    _server: Any
    _frustum_scale: float
    _image_width: int
    _image_interval: float

    def _init_cameras(self) -> None:
        self._cameras: dict[int, CameraSpec] = {}
        self._dirty_cameras: set[int] = set()
        self._images: dict[int, np.ndarray] = {}  # newest accepted BGR image per camera
        self._image_times: dict[int, float] = {}  # when it was accepted (time.monotonic)
        self._dirty_images: set[int] = set()
        # What the worker has drawn; read by cameras() / camera_image() under _cond.
        self._drawn_cameras: dict[int, CameraView] = {}
        self._shown_images: dict[int, np.ndarray] = {}  # RGB, downscaled, as on the frusta
        self._camera_picker: Any = None  # the GUI dropdown, once started

    def _restart_cameras(self) -> None:
        """Under _cond, when the server (re)starts: everything is to be drawn again."""
        self._dirty_cameras = set(self._cameras)
        self._dirty_images = set(self._images)
        self._drawn_cameras = {}

    def _cameras_dirty(self) -> bool:
        return bool(self._dirty_cameras or self._dirty_images)

    def _take_cameras(
        self,
    ) -> tuple[set[int], dict[int, CameraSpec], dict[int, np.ndarray | None]]:
        """Under _cond: the cameras changed since the last call, every camera's spec, and the
        new images (None: the camera's image is gone)."""
        dirty, self._dirty_cameras = self._dirty_cameras, set()
        images = {i: self._images.get(i) for i in self._dirty_images}
        self._dirty_images = set()
        return dirty, dict(self._cameras), images

    # -- state changes (any thread) ----------------------------------------------------------

    def upsert_camera(self, camera: CameraEntry) -> None:
        """Add or redraw a camera.

        K is 3x3 (pixels) or None; T_world_camera is the 4x4 camera-to-world transform (OpenCV
        camera axes: x right, y down, z forward; world Z up) or None, in which case the camera
        is parked beside the floor plan and labelled "uncalibrated pose".
        Raises InvalidInput (nothing changes) for a malformed K or a T that is not rigid.
        """
        spec = parse_camera(camera)
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

    # -- what is drawn -----------------------------------------------------------------------

    def cameras(self) -> dict[int, CameraView]:
        """Return the cameras as currently drawn, by id."""
        with self._cond:
            return dict(self._drawn_cameras)

    def camera_image(self, camera_id: int) -> np.ndarray | None:
        """Return the RGB image currently shown on a camera's frustum (downscaled), or None."""
        with self._cond:
            image = self._shown_images.get(int(camera_id))
        return None if image is None else image.copy()

    # -- GUI: look through a camera -----------------------------------------------------------

    def _add_camera_picker(self, server: Any) -> None:
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

    def _draw_cameras(
        self,
        server: Any,
        dirty: set[int],
        floor_moved: bool,
        cameras: dict[int, CameraSpec],
        rooms: list[RoomView],
    ) -> tuple[set[int], dict[int, CameraView]]:
        """Within the scene's atomic update, after the floor: redraw the cameras in `dirty`,
        and every parked one when the floor plan moved or who is parked changed (they are laid
        out by id beside the plan); return the ids redrawn and the cameras drawn now, for
        `_show_cameras` once the update is sent."""
        drawn = dict(self._drawn_cameras)
        parked = sorted(c.id for c in cameras.values() if c.pose is None)
        was_parked = sorted(i for i, v in drawn.items() if not v.has_pose)
        if floor_moved or parked != was_parked:
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
        return dirty, drawn

    def _show_cameras(self, redrawn: set[int], drawn: dict[int, CameraView]) -> None:
        """Publish the cameras drawn (`_draw_cameras`) to readers and to the picker."""
        with self._cond:
            self._drawn_cameras = drawn
        if redrawn:
            self._refresh_camera_picker()

    @staticmethod
    def _park_origin(rooms: list[RoomView]) -> tuple[float, float]:
        if not rooms:
            return (0.0, -_PARK_OFFSET)
        pts = np.array([p for r in rooms for p in r.polygon])
        return (float(pts[:, 0].min()) + 0.5, float(pts[:, 1].min()) - _PARK_OFFSET)

    def _draw_camera(
        self, server: Any, spec: CameraSpec, origin: tuple[float, float], slot: int
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
            color = COLOR_CALIBRATED if spec.has_intrinsics else _COLOR_NO_INTRINSICS
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
