"""The digital twin's home in the registry: on the first start the space of the simulated
home, its rooms, its cameras (with the home's installed calibration) and its robot; on every
start the scene's projector and printed landmarks that are missing. Only what an installer
knows is entered, never the twin's truth. The running twin is server.services.twin."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from core.sim import Scene
from core.sim.installation import installed_calibration
from core.sim.render import camera_model
from server.db.models import Camera, CameraCalibration, Landmark, Projector, Robot, Room, Space

CAMERA_CALIBRATED = "calibrated"
CAMERA_UNCALIBRATED = "uncalibrated"


def bootstrap_space(session: Session, scene: Scene) -> tuple[int, dict[str, int]]:
    """Create the space, rooms, cameras and robot of `scene` when the registry has no space
    yet; return (space id, camera name -> id) of the space holding the scene's cameras.

    The cameras get the home's installed calibration (core.sim.installation: each camera's own
    chessboard calibration, then the robot's marker drive), status "calibrated", with the
    entry in their history; a camera the drive could not place is registered uncalibrated.
    The twin's true cameras never enter the registry."""
    space = session.scalar(select(Space).order_by(Space.id).limit(1))
    if space is None:
        # Before the first write: a home that is not the shipped one is calibrated by its drive
        # (minutes), which must not hold the database's write lock meanwhile.
        session.rollback()
        installed = {c.name: c for c in installed_calibration(scene).cameras}
        space = Space(name=scene.name, description="the digital twin's home")
        session.add(space)
        session.flush()
        for room in scene.rooms:
            polygon = [[float(x), float(y)] for x, y in room.polygon]
            session.add(Room(space_id=space.id, name=room.name, polygon=polygon))
        for spec in scene.cameras:
            # The resolution is the camera's own, known without calibration.
            model = camera_model(spec)
            cal = installed.get(spec.name)
            camera = Camera(
                space_id=space.id,
                name=spec.name,
                width=model.width,
                height=model.height,
                K=cal.K.tolist() if cal else None,
                dist=cal.dist.tolist() if cal else None,
                T_world_camera=cal.T_world_camera.tolist() if cal else None,
                status=CAMERA_CALIBRATED if cal else CAMERA_UNCALIBRATED,
            )
            session.add(camera)
            if cal is not None:
                session.flush()
                session.add(
                    CameraCalibration(
                        camera_id=camera.id,
                        K=cal.K.tolist(),
                        dist=cal.dist.tolist(),
                        rms=None,
                        image_width=model.width,
                        image_height=model.height,
                    )
                )
        if scene.robot is not None:
            session.add(
                Robot(
                    space_id=space.id,
                    name=scene.robot.name,
                    kinematic_model={
                        "model": "unicycle",
                        "base_radius": scene.robot.base_radius,
                        "base_height": scene.robot.base_height,
                        "limits": scene.robot.limits.model_dump(),
                    },
                )
            )
        session.commit()
    names = [c.name for c in scene.cameras]
    rows = session.execute(
        select(Camera.id, Camera.name).where(Camera.space_id == space.id, Camera.name.in_(names))
    ).all()
    return space.id, {name: id for id, name in rows}


def register_devices(session: Session, space_id: int, scene: Scene) -> None:
    """Register the scene's projector and printed landmarks in space `space_id` where they are
    missing (a projector by name, a landmark by payload), so a restart adds nothing twice and
    what a user changed stays.

    What an installer knows is entered, not the twin's truth: the projector without a pose
    (uncalibrated until a projector calibration run is applied) and the landmarks with their
    kind, payload and printed size but no world pose (the survey locates them)."""
    projector = scene.projector
    if projector is not None:
        known = session.scalar(
            select(Projector.id).where(
                Projector.space_id == space_id, Projector.name == projector.name
            )
        )
        if known is None:
            # A laser spot has no image: the registry's projector-as-camera is 1 x 1 pixels.
            session.add(Projector(space_id=space_id, name=projector.name, width=1, height=1))
    payloads = set(
        session.scalars(select(Landmark.payload).where(Landmark.space_id == space_id)).all()
    )
    for landmark in scene.landmarks:
        if landmark.payload and landmark.payload not in payloads:
            session.add(
                Landmark(
                    space_id=space_id, kind="qr", payload=landmark.payload, size_m=landmark.size
                )
            )
            payloads.add(landmark.payload)
    session.commit()
