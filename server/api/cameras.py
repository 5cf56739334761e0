"""Cameras: image size, intrinsics, distortion, pose; calibration history and export; health
from their camera nodes' heartbeats (or the digital twin's loop, for its cameras)."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, HTTPException, Path, Query, status
from fastapi.responses import PlainTextResponse
from sqlalchemy import select

from server.api._crud import (
    Unassigned,
    apply_changes,
    check_camera_model,
    check_references,
    check_unique_name,
    get_or_404,
    in_space,
    page_of,
    paginate,
)
from server.api.deps import (
    FramesDep,
    HealthDep,
    PageDep,
    ReadAccess,
    SceneDep,
    SessionDep,
    WriteAccess,
)
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Camera, CameraCalibration, Space
from server.schemas.common import MAX_ID, Page
from server.schemas.registry import (
    CameraCalibrationRead,
    CameraCreate,
    CameraHealth,
    CameraHeartbeat,
    CameraRead,
    CameraUpdate,
)
from server.services.calibration import calibration_yaml
from server.services.camera_health import CameraHealthBook

router = APIRouter(prefix="/cameras", tags=["cameras"], responses=PROBLEM_RESPONSES)
CameraId = Annotated[int, Path(ge=1, le=MAX_ID)]


def _with_health(camera: Camera, book: CameraHealthBook) -> CameraRead:
    read = CameraRead.model_validate(camera)
    read.health = book.health(camera.id)
    return read


@router.get("", response_model=Page[CameraRead], dependencies=[ReadAccess])
def list_cameras(
    session: SessionDep,
    page: PageDep,
    book: HealthDep,
    space_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    unassigned: Unassigned = False,
    status: Annotated[Literal["uncalibrated", "nominal", "calibrated"] | None, Query()] = None,
    # PostgreSQL text cannot hold NUL: such a name is refused (422), never a server error.
    name: Annotated[str | None, Query(min_length=1, max_length=200, pattern="^[^\x00]*$")] = None,
):
    """Return a page of cameras with their health, optionally of one space (and those of no
    space), one status or one name."""
    stmt = select(Camera).order_by(Camera.id)
    stmt = in_space(stmt, Camera.space_id, space_id, unassigned)
    if status is not None:
        stmt = stmt.where(Camera.status == status)
    if name is not None:
        stmt = stmt.where(Camera.name == name)
    out = paginate(session, stmt, page)
    out["items"] = [_with_health(camera, book) for camera in out["items"]]
    return out


@router.post(
    "", response_model=CameraRead, status_code=status.HTTP_201_CREATED, dependencies=[WriteAccess]
)
def create_camera(body: CameraCreate, session: SessionDep, scene: SceneDep):
    """Create a camera; intrinsics and pose are optional (the pose as T_world_camera or as
    position + quaternion_xyzw)."""
    check_references(session, {"space_id": (Space, body.space_id)})
    changes = body.changes()
    check_camera_model(None, changes)
    check_unique_name(session, None, Camera, changes, "camera")
    camera = Camera(**changes)
    session.add(camera)
    session.commit()
    scene.camera_changed(camera)
    return camera


@router.get("/{camera_id}", response_model=CameraRead, dependencies=[ReadAccess])
def get_camera(camera_id: CameraId, session: SessionDep, book: HealthDep):
    """Return one camera with its health: online, stalled or offline since when, from its
    camera node's heartbeats."""
    return _with_health(get_or_404(session, Camera, camera_id, "camera"), book)


@router.post("/{camera_id}/heartbeat", response_model=CameraHealth, dependencies=[WriteAccess])
def camera_heartbeat(
    camera_id: CameraId, body: CameraHeartbeat, session: SessionDep, book: HealthDep
):
    """Record a camera node's report on the camera (every second); return its health. No
    report for 5 s makes the camera offline."""
    get_or_404(session, Camera, camera_id, "camera")
    return book.beat(camera_id, body)


@router.patch("/{camera_id}", response_model=CameraRead, dependencies=[WriteAccess])
def update_camera(camera_id: CameraId, body: CameraUpdate, session: SessionDep, scene: SceneDep):
    """Change the fields given (null clears an optional one)."""
    camera = get_or_404(session, Camera, camera_id, "camera")
    changes = body.changes()
    check_references(session, {"space_id": (Space, changes.get("space_id"))})
    check_unique_name(session, camera, Camera, changes, "camera")
    check_camera_model(camera, changes)
    apply_changes(camera, changes)
    session.commit()
    scene.camera_changed(camera)
    return camera


@router.delete("/{camera_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess])
def delete_camera(
    camera_id: CameraId,
    session: SessionDep,
    scene: SceneDep,
    book: HealthDep,
    frames: FramesDep,
) -> None:
    """Delete a camera and its calibration history (its runs stay, unassigned)."""
    session.delete(get_or_404(session, Camera, camera_id, "camera"))
    session.commit()
    scene.camera_removed(camera_id)
    book.forget(camera_id)
    frames.forget(camera_id)  # its node's last frame


@router.get(
    "/{camera_id}/calibrations",
    response_model=Page[CameraCalibrationRead],
    dependencies=[ReadAccess],
)
def list_camera_calibrations(camera_id: CameraId, session: SessionDep, page: PageDep):
    """Return the camera's calibration history, newest first."""
    get_or_404(session, Camera, camera_id, "camera")
    return page_of(session, CameraCalibration, CameraCalibration.camera_id, camera_id, page)


@router.get(
    "/{camera_id}/calibration.yaml",
    response_class=PlainTextResponse,
    dependencies=[ReadAccess],
    responses={200: {"content": {"application/yaml": {}}}},
)
def export_camera_calibration(
    camera_id: CameraId,
    session: SessionDep,
    format: Annotated[Literal["opencv", "ros"], Query(description="File layout.")] = "opencv",
) -> PlainTextResponse:
    """Return the camera's calibration as OpenCV FileStorage YAML or ROS camera_info YAML."""
    camera = get_or_404(session, Camera, camera_id, "camera")
    if camera.K is None or camera.dist is None:
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail=f"camera {camera_id} has no intrinsics yet; apply a calibration run first",
        )
    rms = session.scalar(
        select(CameraCalibration.rms)
        .where(
            CameraCalibration.camera_id == camera_id,
            CameraCalibration.calibration_run_id == camera.calibration_run_id,
        )
        .order_by(CameraCalibration.id.desc())
        .limit(1)
    )
    text = calibration_yaml(
        camera.K,
        camera.dist,
        (camera.width, camera.height),
        format,
        camera_name=camera.name,
        rms=rms if camera.calibration_run_id is not None else None,
    )
    filename = f"camera-{camera_id}-{format}.yaml"
    return PlainTextResponse(
        text,
        media_type="application/yaml",
        headers={"Content-Disposition": f'attachment; filename="{filename}"'},
    )
