"""Pushes registry changes (rooms, cameras) to the live 3D scene after they are committed.

The scene shows one space at a time (the first, the twin's home, until another is chosen with
PUT /scene): its rooms, cameras, landmarks and maps, and the devices of no space; another
space's are left out, so two homes are never drawn over each other. The scene's methods only
record the change and return; drawing happens on its own thread. A scene failure is logged and
never fails the request that caused it."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from sqlalchemy import or_, select
from sqlalchemy.orm import Session, object_session

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
from server.scene import (
    ArmEntry,
    CameraEntry,
    LandmarkEntry,
    PlaceEntry,
    ProjectorEntry,
    RoomEntry,
    SemanticObjectEntry,
)

if TYPE_CHECKING:
    from server.scene import SceneService

log = logging.getLogger(__name__)

# The robot the scene shows (server.services.twin draws it as this agent): the twin's, which
# the twin registers as the only robot of the first space when it starts.
ROBOT_AGENT = "robot"


def camera_entry(camera: Camera) -> CameraEntry:
    """Return a camera as the scene takes it."""
    return CameraEntry(
        camera.id, camera.name, camera.width, camera.height, camera.K, camera.T_world_camera
    )


def arm_entry(arm: Arm, agent: str, q: Any = None) -> ArmEntry:
    """Return an arm on the robot drawn as `agent` as the scene takes it, at joint values q
    (None: home)."""
    return ArmEntry(
        id=str(arm.id),
        agent=agent,
        name=arm.name,
        dh=arm.dh,
        limits=arm.limits,
        tool=arm.tool,
        home=arm.home,
        T_robot_arm=arm.T_robot_arm,
        q=None if q is None else [float(v) for v in q],
    )


def first_space(session: Session) -> int | None:
    """Return the id of the first space (the twin's home when the twin runs), None if none."""
    return session.scalar(select(Space.id).order_by(Space.id).limit(1))


def shown_robot_arms(session: Session, space_id: int | None = None) -> list[Arm]:
    """Return the arms of the robot the scene shows (the first robot of `space_id`, by default
    the first space's)."""
    space = first_space(session) if space_id is None else space_id
    robot = session.scalar(
        select(Robot.id).where(Robot.space_id == space).order_by(Robot.id).limit(1)
    )
    if robot is None:
        return []
    return list(session.scalars(select(Arm).where(Arm.robot_id == robot).order_by(Arm.id)))


def landmark_entries(session: Session, space_id: int | None = None) -> list[LandmarkEntry]:
    """Return every registry landmark with a pose (of one space when `space_id` is given) as
    the scene takes it: a QR landmark named by its payload ("#id name", kind "object" or
    "signpost"), any other by its id."""
    stmt = select(Landmark).where(Landmark.T_world_landmark.is_not(None))
    if space_id is not None:
        stmt = stmt.where(or_(Landmark.space_id == space_id, Landmark.space_id.is_(None)))
    rows = session.scalars(stmt.order_by(Landmark.id))
    out = []
    for row in rows:
        if row.T_world_landmark is None:
            continue  # a JSON null: not SQL's NULL, so the query lets it through
        name, kind = f"landmark {row.id}", row.kind
        try:
            record = decode_payload(row.payload)
            name, kind = f"#{record.id} {record.name}", record.kind
        except PayloadError:
            pass  # a foreign code (ArUco, another QR): shown by its registry id and kind
        out.append(LandmarkEntry(row.id, name, kind, row.size_m, row.T_world_landmark))
    return out


def semantic_entries(session: Session, space_id: int | None = None) -> list[SemanticObjectEntry]:
    """Return the semantic objects (id "space:mark") of every space, or of one, as the scene
    takes them."""
    stmt = select(SemanticObject)
    if space_id is not None:
        stmt = stmt.where(SemanticObject.space_id == space_id)
    rows = session.scalars(stmt.order_by(SemanticObject.space_id, SemanticObject.mark_id))
    return [
        SemanticObjectEntry(
            f"{r.space_id}:{r.mark_id}", r.name, r.object_class, r.room, r.T_world_mark
        )
        for r in rows
    ]


def navigation_entries(
    session: Session, space_id: int | None = None
) -> tuple[list[PlaceEntry], list[list[str]]]:
    """Return the navigation places (id "space:mark", at the pose their payload carries) and
    edges of every space, or of one, as the scene takes them."""
    place_stmt = select(NavigationPlace)
    edge_stmt = select(NavigationEdge)
    if space_id is not None:
        place_stmt = place_stmt.where(NavigationPlace.space_id == space_id)
        edge_stmt = edge_stmt.where(NavigationEdge.space_id == space_id)
    places = session.scalars(place_stmt.order_by(NavigationPlace.space_id, NavigationPlace.mark_id))
    edges = session.scalars(edge_stmt.order_by(NavigationEdge.id))
    return (
        [PlaceEntry(f"{p.space_id}:{p.mark_id}", p.name, p.room, p.pose[:3]) for p in places],
        [[f"{e.space_id}:{e.from_mark}", f"{e.space_id}:{e.to_mark}"] for e in edges],
    )


class SceneSync:
    """The API's handle on the scene; every method is a no-op when the scene is disabled."""

    def __init__(self, scene: SceneService | None) -> None:
        self.scene = scene
        # The space the scene shows; None until `load` or `show` picks one.
        self.space_id: int | None = None

    def _space(self, session: Session) -> int | None:
        """Return the space shown: the chosen one while it exists, else the first."""
        if self.space_id is None or session.get(Space, self.space_id) is None:
            self.space_id = first_space(session)
        return self.space_id

    def shows(self, space_id: int | None) -> bool:
        """Return whether the scene runs here and shows space `space_id`."""
        return self.scene is not None and space_id is not None and space_id == self.space_id

    def show(self, session: Session, space_id: int) -> None:
        """Show space `space_id` instead of the one shown: the other space's cameras leave the
        scene, this one's floor plan, cameras, robot arms, landmarks and maps come in."""
        if self.scene is None:
            return
        self.space_id = space_id
        keep = set(
            session.scalars(
                select(Camera.id).where(or_(Camera.space_id == space_id, Camera.space_id.is_(None)))
            )
        )
        try:
            shown = list(self.scene.cameras())
        except Exception:
            log.exception("reading the scene's cameras failed")
            shown = []
        for camera_id in shown:
            if camera_id not in keep:
                self._call("remove_camera", camera_id)
        for arm_id in self._shown_arms():
            self._call("remove_arm", arm_id)
        self.load(session)

    def _shown_arms(self) -> list[str]:
        try:
            return list(self.scene.arms()) if self.scene is not None else []
        except Exception:
            log.exception("reading the scene's arms failed")
            return []

    def rooms_changed(self, session: Session) -> None:
        """Send the floor plan (every room of the space shown) to the scene."""
        if self.scene is None:
            return
        stmt = select(Room).where(Room.space_id == self._space(session))
        rooms = session.scalars(stmt.order_by(Room.id)).all()
        self._call("set_floor_plan", [RoomEntry(r.id, r.name, r.polygon) for r in rooms])

    def camera_changed(self, camera: Camera) -> None:
        """Send one camera's (new) state to the scene; a camera of another space than the
        one shown leaves it (it may have just been moved there)."""
        if self.scene is None:
            return
        session = object_session(camera)
        if session is not None:
            self._space(session)
        if camera.space_id is None or camera.space_id == self.space_id:
            self._call("upsert_camera", camera_entry(camera))
        else:
            self._call("remove_camera", camera.id)

    def camera_removed(self, camera_id: int) -> None:
        """Remove a camera from the scene."""
        if self.scene is not None:
            self._call("remove_camera", camera_id)

    def arm_changed(self, arm: Arm, q: Any = None, agent: str = ROBOT_AGENT) -> None:
        """Draw an arm on the robot shown as `agent`, at joint values q (default: home)."""
        if self.scene is not None:
            self._call("set_arm", arm_entry(arm, agent, q))

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
        entry = ProjectorEntry(projector.name, projector.T_world_projector, spot)
        self._call("set_projector", entry)

    def landmarks_changed(self, session: Session) -> None:
        """Send every placed landmark of the space shown to the scene."""
        if self.scene is not None:
            self._call("set_landmarks", landmark_entries(session, self._space(session)))

    def maps_changed(self, session: Session) -> None:
        """Send the semantic and navigation maps of the space shown to the scene."""
        if self.scene is None:
            return
        space_id = self._space(session)
        self._call("set_semantic_objects", semantic_entries(session, space_id))
        self._call("set_navigation_graph", *navigation_entries(session, space_id))

    def load(self, session: Session) -> None:
        """Send the floor plan, the cameras and the arms of the robot (at home) of the space
        shown (the first space unless one was chosen), its placed landmarks and its maps, e.g.
        when the scene starts."""
        space_id = self._space(session)
        if self.scene is None:
            return
        self.rooms_changed(session)
        cameras = select(Camera).where(or_(Camera.space_id == space_id, Camera.space_id.is_(None)))
        for camera in session.scalars(cameras.order_by(Camera.id)):
            self.camera_changed(camera)
        for arm in shown_robot_arms(session, space_id):
            self.arm_changed(arm)
        self.landmarks_changed(session)
        self.maps_changed(session)

    def _call(self, method: str, *args: Any) -> None:
        try:
            getattr(self.scene, method)(*args)
        except Exception:
            log.exception("scene update %s failed", method)
