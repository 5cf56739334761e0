"""The live 3D scene: a viser server showing the floor plan, every camera's frustum with its
latest image, the robots and people on the floor with their tracks, their arms, the planned
path and the projector, and the landmarks with the maps they build.

Callers (the API, after a database commit) only record the desired state and wake a worker
thread; the worker redraws what changed. So a call never waits on viser or on a slow client,
bursts of updates to one camera collapse into one redraw, and the scene follows within a few
milliseconds (the contract is "within a second"). Each kind of thing drawn is a layer of its
own module (`_floor`, `_cameras`, `_agents`, `_navigation`, `_arm`, `_landmarks`); this module
runs the server and the worker that draws them.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator
from typing import Any

from core.errors import InvalidInput
from server.scene._agents import AgentLayer
from server.scene._arm import ArmLayer
from server.scene._cameras import COLOR_CALIBRATED, CameraLayer, CameraSpec
from server.scene._floor import FloorLayer, RoomView
from server.scene._landmarks import LandmarkLayer
from server.scene._navigation import NavigationLayer

log = logging.getLogger(__name__)


class SceneService(FloorLayer, CameraLayer, AgentLayer, NavigationLayer, ArmLayer, LandmarkLayer):
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
        self._cond = threading.Condition()  # guards the layers' state; held only briefly
        self._lifecycle = threading.Lock()  # serialises start() and stop()
        self._busy = False
        self._stopping = False
        self._worker: threading.Thread | None = None
        self._init_floor()
        self._init_cameras()
        self._init_agents()
        self._init_navigation()
        self._init_arms()
        self._init_landmarks()
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
                show_share_button=False, brand_color=COLOR_CALIBRATED, control_width="small"
            )
            self._refuse_share_urls(server)
            self._add_camera_picker(server)
            with self._cond:
                self._server = server
                self._port = server.get_port()
                self._stopping = False
                self._restart_floor()
                self._restart_cameras()
                self._restart_agents()
                self._restart_navigation()
                self._restart_arms()
                self._restart_landmarks()
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
            self._cameras_dirty()
            or self._floor_dirty()
            or self._agents_dirty()
            or self._navigation_dirty()
            or self._arms_dirty()
            or self._landmarks_dirty()
        )

    # -- drawing (worker thread) -------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stopping or self._anything_dirty())
                if self._stopping:
                    return
                dirty, cameras, images = self._take_cameras()
                floor_dirty, rooms = self._take_floor()
                moved, tracks = self._take_agents()
                navigation = self._take_navigation()
                arms = self._take_arms()
                landmark_layers = self._take_landmarks()
                self._busy = True
            try:
                self._draw_images(images)  # before the cameras, which may be redrawn with them
                self._draw_floor_and_cameras(dirty, floor_dirty, cameras, rooms)
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

    def _draw_floor_and_cameras(
        self,
        dirty: set[int],
        floor_dirty: bool,
        cameras: dict[int, CameraSpec],
        rooms: list[RoomView],
    ) -> None:
        """Redraw the floor plan and the cameras in one atomic update: the parked cameras sit
        in a row beside the plan, so a new plan moves them."""
        server = self._server
        if server is None:
            return
        with server.atomic():
            if floor_dirty:
                self._draw_floor(server, rooms)
            redrawn, drawn = self._draw_cameras(server, dirty, floor_dirty, cameras, rooms)
        self._show_cameras(redrawn, drawn)
