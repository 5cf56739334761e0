"""Pushes registry changes (rooms, cameras) to the live 3D scene after they are committed.

The scene's methods only record the change and return; drawing happens on its own thread. A
scene failure is logged and never fails the request that caused it."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from server.db.models import Camera, Room

if TYPE_CHECKING:
    from server.scene import SceneService

log = logging.getLogger(__name__)


def camera_view(camera: Camera) -> dict[str, Any]:
    """Return the scene's description of a camera."""
    return {
        "id": camera.id,
        "name": camera.name,
        "width": camera.width,
        "height": camera.height,
        "K": camera.K,
        "T_world_camera": camera.T_world_camera,
    }


class SceneSync:
    """The API's handle on the scene; every method is a no-op when the scene is disabled."""

    def __init__(self, scene: SceneService | None) -> None:
        self.scene = scene

    def rooms_changed(self, session: Session) -> None:
        """Send the whole floor plan (every room) to the scene."""
        if self.scene is None:
            return
        rooms = session.scalars(select(Room).order_by(Room.id)).all()
        plan = [{"id": r.id, "name": r.name, "polygon": r.polygon} for r in rooms]
        self._call("set_floor_plan", plan)

    def camera_changed(self, camera: Camera) -> None:
        """Send one camera's (new) state to the scene."""
        if self.scene is not None:
            self._call("upsert_camera", camera_view(camera))

    def camera_removed(self, camera_id: int) -> None:
        """Remove a camera from the scene."""
        if self.scene is not None:
            self._call("remove_camera", camera_id)

    def load(self, session: Session) -> None:
        """Send the floor plan and every camera, e.g. when the scene starts."""
        if self.scene is None:
            return
        self.rooms_changed(session)
        for camera in session.scalars(select(Camera).order_by(Camera.id)):
            self.camera_changed(camera)

    def _call(self, method: str, *args: Any) -> None:
        try:
            getattr(self.scene, method)(*args)
        except Exception:
            log.exception("scene update %s failed", method)
