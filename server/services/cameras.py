"""A camera of the registry as the core camera the localisation takes: the one place a camera
row (server.db.models.Camera, or the same fields stored in a run's inputs or sent as JSON)
becomes a core.localization.NetworkCamera; and the registry's cameras of given ids as those
core cameras, with the reason each unusable one cannot measure."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from core.errors import InvalidInput
from core.localization import NetworkCamera
from server.db.models import Camera

# What the adapter reads of a camera.
_FIELDS = ("K", "dist", "T_world_camera", "width", "height", "name")


class CameraNotPlaced(InvalidInput):
    """A camera without intrinsics K or without a pose T_world_camera: it cannot measure yet.
    `missing` names what it lacks ("intrinsics K" or "pose T_world_camera")."""

    def __init__(self, name: str, missing: str) -> None:
        super().__init__(f"camera {name!r} has no {missing}: calibrate or place it")
        self.missing = missing


def network_camera(row: Camera | Mapping[str, Any]) -> NetworkCamera:
    """Return the core camera of a registry camera (a row, or a mapping of its fields K, dist,
    T_world_camera, width, height and name). Raises CameraNotPlaced when it has no K or no
    pose, core's InvalidInput when its model cannot be used."""
    fields: Mapping[str, Any] = (
        row
        if isinstance(row, Mapping)
        else {
            k: getattr(row, k) for k in ("K", "dist", "T_world_camera", "width", "height", "name")
        }
    )
    name = str(fields["name"])
    if fields["K"] is None:
        raise CameraNotPlaced(name, "intrinsics K")
    if fields["T_world_camera"] is None:
        raise CameraNotPlaced(name, "pose T_world_camera")
    return NetworkCamera.from_pose(
        fields["K"],
        fields.get("dist"),
        fields["T_world_camera"],
        (fields["width"], fields["height"]),
        name,
    )


def registry_cameras(
    session: Session, ids: list[int]
) -> tuple[dict[int, NetworkCamera], dict[int, str]]:
    """Return the NetworkCamera of each camera of `ids` that has K and a pose, and the reason
    for each one that cannot be used."""
    usable: dict[int, NetworkCamera] = {}
    refused: dict[int, str] = {}
    found = {c.id: c for c in session.scalars(select(Camera).where(Camera.id.in_(ids)))}
    for camera_id in ids:
        camera = found.get(camera_id)
        if camera is None:
            refused[camera_id] = f"no camera with id {camera_id}"
            continue
        try:
            usable[camera_id] = network_camera(camera)
        except CameraNotPlaced as exc:
            refused[camera_id] = f"camera {camera_id} ({camera.name}) has no {exc.missing}"
    return usable, refused
