"""Cameras: image size, intrinsics, distortion, pose; calibration history and export."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, HTTPException, Path, Query, status
from fastapi.responses import PlainTextResponse
from sqlalchemy import select

from server.api._crud import apply_changes, check_references, get_or_404, paginate
from server.api.deps import PageDep, ReadAccess, SceneDep, SessionDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Camera, CameraCalibration, Space
from server.schemas.common import MAX_ID, Page
from server.schemas.registry import CameraCalibrationRead, CameraCreate, CameraRead, CameraUpdate
from server.services.calibration import calibration_yaml

router = APIRouter(prefix="/cameras", tags=["cameras"], responses=PROBLEM_RESPONSES)
CameraId = Annotated[int, Path(ge=1, le=MAX_ID)]


@router.get("", response_model=Page[CameraRead], dependencies=[ReadAccess])
def list_cameras(
    session: SessionDep,
    page: PageDep,
    space_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    status: Annotated[Literal["uncalibrated", "nominal", "calibrated"] | None, Query()] = None,
):
    """Return a page of cameras, optionally of one space or one status."""
    stmt = select(Camera).order_by(Camera.id)
    if space_id is not None:
        stmt = stmt.where(Camera.space_id == space_id)
    if status is not None:
        stmt = stmt.where(Camera.status == status)
    return paginate(session, stmt, page)


@router.post(
    "", response_model=CameraRead, status_code=status.HTTP_201_CREATED, dependencies=[WriteAccess]
)
def create_camera(body: CameraCreate, session: SessionDep, scene: SceneDep):
    """Create a camera; intrinsics and pose are optional (the pose as T_world_camera or as
    position + quaternion_xyzw)."""
    check_references(session, {"space_id": (Space, body.space_id)})
    camera = Camera(**body.changes())
    session.add(camera)
    session.commit()
    scene.camera_changed(camera)
    return camera


@router.get("/{camera_id}", response_model=CameraRead, dependencies=[ReadAccess])
def get_camera(camera_id: CameraId, session: SessionDep):
    """Return one camera."""
    return get_or_404(session, Camera, camera_id, "camera")


@router.patch("/{camera_id}", response_model=CameraRead, dependencies=[WriteAccess])
def update_camera(camera_id: CameraId, body: CameraUpdate, session: SessionDep, scene: SceneDep):
    """Change the fields given (null clears an optional one)."""
    camera = get_or_404(session, Camera, camera_id, "camera")
    changes = body.changes()
    check_references(session, {"space_id": (Space, changes.get("space_id"))})
    apply_changes(camera, changes)
    session.commit()
    scene.camera_changed(camera)
    return camera


@router.delete("/{camera_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess])
def delete_camera(camera_id: CameraId, session: SessionDep, scene: SceneDep) -> None:
    """Delete a camera and its calibration history (its runs stay, unassigned)."""
    session.delete(get_or_404(session, Camera, camera_id, "camera"))
    session.commit()
    scene.camera_removed(camera_id)


@router.get(
    "/{camera_id}/calibrations",
    response_model=Page[CameraCalibrationRead],
    dependencies=[ReadAccess],
)
def list_camera_calibrations(camera_id: CameraId, session: SessionDep, page: PageDep):
    """Return the camera's calibration history, newest first."""
    get_or_404(session, Camera, camera_id, "camera")
    stmt = (
        select(CameraCalibration)
        .where(CameraCalibration.camera_id == camera_id)
        .order_by(CameraCalibration.id.desc())
    )
    return paginate(session, stmt, page)


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
