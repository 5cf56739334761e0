"""Pushes registry changes (rooms, cameras) to the live 3D scene after they are committed.

The scene's methods only record the change and return; drawing happens on its own thread. A
scene failure is logged and never fails the request that caused it."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from core.landmarks import PayloadError, decode_payload
from server.db.models import (
    Arm,
    Camera,
    Landmark,
    NavigationEdge,
    NavigationPlace,
    Projector,
    Robot,
    Room,
    SemanticObject,
    Space,
)

if TYPE_CHECKING:
    from server.scene import SceneService

log = logging.getLogger(__name__)

# The robot the scene shows (server.services.twin draws it as this agent): the twin's, which
# the twin registers as the only robot of the first space when it starts.
ROBOT_AGENT = "robot"


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


def arm_view(arm: Arm, agent: str, q: Any = None) -> dict[str, Any]:
    """Return the scene's description of an arm on the robot drawn as `agent`."""
    fields = ("dh", "limits", "tool", "home", "T_robot_arm")
    return {
        "id": str(arm.id),
        "agent": agent,
        "name": arm.name,
        **{key: getattr(arm, key) for key in fields},
        "q": None if q is None else [float(v) for v in q],
    }


def shown_robot_arms(session: Session) -> list[Arm]:
    """Return the arms of the robot the scene shows (the first space's first robot)."""
    space = select(Space.id).order_by(Space.id).limit(1).scalar_subquery()
    robot = session.scalar(
        select(Robot.id).where(Robot.space_id == space).order_by(Robot.id).limit(1)
    )
    if robot is None:
        return []
    return list(session.scalars(select(Arm).where(Arm.robot_id == robot).order_by(Arm.id)))


def landmark_views(session: Session) -> list[dict[str, Any]]:
    """Return the scene's description of every registry landmark with a pose: a QR landmark
    named by its payload ("#id name", kind "object" or "signpost"), any other by its id."""
    rows = session.scalars(
        select(Landmark).where(Landmark.T_world_landmark.is_not(None)).order_by(Landmark.id)
    )
    out = []
    for row in rows:
        name, kind = f"landmark {row.id}", row.kind
        try:
            record = decode_payload(row.payload)
            name, kind = f"#{record.id} {record.name}", record.kind
        except PayloadError:
            pass  # a foreign code (ArUco, another QR): shown by its registry id and kind
        view = {"id": row.id, "name": name, "kind": kind, "size": row.size_m}
        out.append({**view, "T_world_landmark": row.T_world_landmark})
    return out


def semantic_views(session: Session) -> list[dict[str, Any]]:
    """Return the scene's description of every space's semantic objects (id "space:mark")."""
    rows = session.scalars(
        select(SemanticObject).order_by(SemanticObject.space_id, SemanticObject.mark_id)
    )
    return [
        {
            "id": f"{r.space_id}:{r.mark_id}",
            "name": r.name,
            "class": r.object_class,
            "room": r.room,
            "T_world_mark": r.T_world_mark,
        }
        for r in rows
    ]


def navigation_views(session: Session) -> tuple[list[dict[str, Any]], list[list[str]]]:
    """Return every space's navigation places (id "space:mark", at the pose their payload
    carries) and edges, as the scene takes them."""
    places = session.scalars(
        select(NavigationPlace).order_by(NavigationPlace.space_id, NavigationPlace.mark_id)
    )
    edges = session.scalars(select(NavigationEdge).order_by(NavigationEdge.id))
    return (
        [
            {
                "id": f"{p.space_id}:{p.mark_id}",
                "name": p.name,
                "room": p.room,
                "position": p.pose[:3],
            }
            for p in places
        ],
        [[f"{e.space_id}:{e.from_mark}", f"{e.space_id}:{e.to_mark}"] for e in edges],
    )


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

    def arm_changed(self, arm: Arm, q: Any = None, agent: str = ROBOT_AGENT) -> None:
        """Draw an arm on the robot shown as `agent`, at joint values q (default: home)."""
        if self.scene is not None:
            self._call("set_arm", arm_view(arm, agent, q))

    def arm_joints(self, arm_id: int, q: Any) -> None:
        """Move a drawn arm's joints to q (6,) rad (a task reporting its arm's motion)."""
        if self.scene is not None:
            self._call("set_arm_joints", str(arm_id), q)

    def arm_gripper(self, arm_id: int, opening: float) -> None:
        """Open or close a drawn arm's gripper to `opening` metres (a task reporting it)."""
        if self.scene is not None:
            self._call("set_arm_gripper", str(arm_id), opening)

    def arm_box(self, arm_id: int, T_arm_box: Any) -> None:
        """Draw the box a drawn arm's task is fetching, or move it, to T_arm_box (4, 4): its
        mark frame (the top's centre) in the arm's base frame (a task reporting it)."""
        if self.scene is not None:
            self._call("set_arm_box", str(arm_id), T_arm_box)

    def arm_box_removed(self, arm_id: int) -> None:
        """Take a drawn arm's box out of the scene (its task ended)."""
        if self.scene is not None:
            self._call("remove_arm_box", str(arm_id))

    def projector_changed(self, projector: Projector) -> None:
        """Redraw the projector at its (newly applied) pose T_world_projector, its beam still
        on the floor spot it was drawn to; nothing when it has no pose."""
        if self.scene is None or projector.T_world_projector is None:
            return
        shown = self.scene.projector()
        spot = shown.spot if shown is not None and shown.name == projector.name else None
        view = {"name": projector.name, "T_world_projector": projector.T_world_projector}
        self._call("set_projector", {**view, "spot": spot})

    def landmarks_changed(self, session: Session) -> None:
        """Send every placed landmark of the registry to the scene."""
        if self.scene is not None:
            self._call("set_landmarks", landmark_views(session))

    def maps_changed(self, session: Session) -> None:
        """Send the semantic and navigation maps (every space's) to the scene."""
        if self.scene is None:
            return
        self._call("set_semantic_objects", semantic_views(session))
        self._call("set_navigation_graph", *navigation_views(session))

    def load(self, session: Session) -> None:
        """Send the floor plan, every camera and the arms of the robot the scene shows (at
        home), the placed landmarks and the maps, e.g. when the scene starts."""
        if self.scene is None:
            return
        self.rooms_changed(session)
        for camera in session.scalars(select(Camera).order_by(Camera.id)):
            self.camera_changed(camera)
        for arm in shown_robot_arms(session):
            self.arm_changed(arm)
        self.landmarks_changed(session)
        self.maps_changed(session)

    def _call(self, method: str, *args: Any) -> None:
        try:
            getattr(self.scene, method)(*args)
        except Exception:
            log.exception("scene update %s failed", method)
