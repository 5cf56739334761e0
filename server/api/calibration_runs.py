"""Calibration runs: submitted (202), executed off the event loop, read back, applied."""

from __future__ import annotations

import re
from typing import Annotated

from fastapi import (
    APIRouter,
    Depends,
    File,
    Form,
    HTTPException,
    Path,
    Query,
    Request,
    UploadFile,
    status,
)
from pydantic import Field
from sqlalchemy import or_, select, update

from server.api._crud import check_references, get_or_404, paginate
from server.api.arms import apply_hand_eye_run, hand_eye_run
from server.api.deps import (
    PageDep,
    ReadAccess,
    SceneDep,
    SessionDep,
    SettingsDep,
    WriteAccess,
    get_executor,
)
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.api.limits import check_image_size
from server.api.paths import apply_projector_run, projector_run
from server.db.base import utcnow
from server.db.models import (
    RUN_SUCCEEDED,
    CalibrationRun,
    CalibrationRunFile,
    Camera,
    CameraCalibration,
)
from server.schemas.calibration import (
    CalibrationRunRead,
    DistortionModel,
    IntrinsicsRunCreate,
    RunStatus,
    implausible_square,
)
from server.schemas.common import MAX_ID, Page
from server.schemas.manipulation import ArmRead, HandEyeRunCreate
from server.schemas.paths import ProjectorRunCreate
from server.schemas.registry import CameraRead, ProjectorRead
from server.schemas.twin import NetworkRunCreate
from server.services.calibration import decode_image
from server.services.placement import placement_values
from server.services.runs import RunExecutor

router = APIRouter(
    prefix="/calibration-runs", tags=["calibration runs"], responses=PROBLEM_RESPONSES
)
RunId = Annotated[int, Path(ge=1, le=MAX_ID)]
ExecutorDep = Annotated[RunExecutor | None, Depends(get_executor)]
_PATTERN = re.compile(r"^\s*(\d{1,3})\s*[xX]\s*(\d{1,3})\s*$")


def _queue(session, executor: RunExecutor | None, run: CalibrationRun) -> CalibrationRun:
    session.add(run)
    session.commit()
    if executor is not None:
        executor.submit(run.id)
    return run


@router.post(
    "",
    response_model=CalibrationRunRead,
    status_code=status.HTTP_202_ACCEPTED,
    dependencies=[WriteAccess],
)
def create_calibration_run(
    body: Annotated[
        IntrinsicsRunCreate | NetworkRunCreate | HandEyeRunCreate | ProjectorRunCreate,
        Field(discriminator="kind"),
    ],
    session: SessionDep,
    executor: ExecutorDep,
    request: Request,
):
    """Queue a calibration; poll GET /calibration-runs/{id}. Kind "intrinsics": Zhang's method
    on point correspondences of one camera. Kind "network": the twin's calibration drive (the
    robot's marker driven over the floor) calibrates every twin camera, intrinsics and pose.
    Kind "hand-eye": an arm's eye-in-hand camera, on the twin or from uploaded pose pairs.
    Kind "projector": the twin's projector's mount, from spots the ceiling cameras locate."""
    if isinstance(body, ProjectorRunCreate):
        return _queue(session, executor, projector_run(body, session, request))
    if isinstance(body, HandEyeRunCreate):
        twin = getattr(request.app.state, "twin", None)
        return _queue(session, executor, hand_eye_run(body, session, twin is not None))
    if isinstance(body, NetworkRunCreate):
        twin = getattr(request.app.state, "twin", None)
        if twin is None:
            raise HTTPException(
                status.HTTP_409_CONFLICT,
                detail="a network run drives the digital twin's robot; start the service with "
                "INTSPACE_SIMULATION=true",
            )
        run = CalibrationRun(
            kind="network",
            source="twin",
            camera_id=None,
            inputs={"space_id": twin.space_id, "cameras": dict(twin.camera_ids)},
            options=body.options.model_dump(),
        )
        return _queue(session, executor, run)
    check_references(session, {"camera_id": (Camera, body.camera_id)})
    _check_image_size(session, body.camera_id, tuple(body.image_size), "image_size", "body")
    run = CalibrationRun(
        kind=body.kind,
        source="correspondences",
        camera_id=body.camera_id,
        inputs=body.model_dump(include={"image_size", "object_points", "image_points"}),
        options=body.options.model_dump(),
    )
    return _queue(session, executor, run)


def _check_image_size(
    session, camera_id: int, size: tuple[int, ...], field: str, location: str
) -> None:
    """Refuse (409) a run whose images are not the size of its camera's: its result could
    never be applied to that camera."""
    camera = session.get(Camera, camera_id)
    if camera is not None and (camera.width, camera.height) != size:
        raise FieldProblem(
            409,
            field,
            f"the images are {size[0]}x{size[1]} but camera {camera_id} is "
            f"{camera.width}x{camera.height}; calibrate with images of the camera's size or "
            "fix the camera's width and height first",
            location,
        )


@router.post(
    "/upload",
    response_model=CalibrationRunRead,
    status_code=status.HTTP_202_ACCEPTED,
    dependencies=[WriteAccess],
)
def upload_calibration_run(
    session: SessionDep,
    settings: SettingsDep,
    executor: ExecutorDep,
    camera_id: Annotated[int, Form(ge=1, le=MAX_ID)],
    files: Annotated[list[UploadFile], File(description="Photos of the chessboard.")],
    chessboard: Annotated[
        str, Form(max_length=20, description="Inner corners, columns x rows, e.g. 9x6.")
    ] = "9x6",
    square: Annotated[
        float, Form(gt=0, allow_inf_nan=False, description="Side of a square, metres (<= 1).")
    ] = 0.025,
    distortion: Annotated[DistortionModel, Form()] = "k1k2p1p2",
    skew: Annotated[bool, Form()] = False,
):
    """Queue an intrinsic calibration from photos of a chessboard (PNG, JPEG, ...; every
    image the same size). Photos where the board is not found are skipped by the run."""
    match = _PATTERN.match(chessboard)
    if match is None or min(int(match[1]), int(match[2])) < 2:
        raise FieldProblem(
            422, "chessboard", "give the inner corners as COLSxROWS, e.g. 9x6", "form"
        )
    cols, rows = int(match[1]), int(match[2])
    if (why := implausible_square(square)) is not None:
        raise FieldProblem(422, "square", why, "form")
    check_references(session, {"camera_id": (Camera, camera_id)})
    if len(files) > settings.max_upload_files:
        raise FieldProblem(
            413, "files", f"at most {settings.max_upload_files} images per run", "form"
        )

    blobs: list[CalibrationRunFile] = []
    size: tuple[int, int] | None = None
    for position, upload in enumerate(files):
        name = (upload.filename or f"image-{position}").replace("\x00", "")[-255:]
        data = upload.file.read(settings.max_upload_file_bytes + 1)
        if len(data) > settings.max_upload_file_bytes:
            raise FieldProblem(
                413,
                f"files.{position}",
                f"{name!r} exceeds {settings.max_upload_file_bytes} bytes",
                "form",
            )
        check_image_size(data, settings.max_image_pixels, f"files.{position}", name)
        image = decode_image(data, settings.max_image_pixels)
        if image is None:
            raise FieldProblem(
                415, f"files.{position}", f"{name!r} is not an image OpenCV can decode", "form"
            )
        this_size = (int(image.shape[1]), int(image.shape[0]))
        if size is not None and this_size != size:
            raise FieldProblem(
                422,
                f"files.{position}",
                f"{name!r} is {this_size[0]}x{this_size[1]} but the first image is "
                f"{size[0]}x{size[1]}; every photo must come from the same camera mode",
                "form",
            )
        size = this_size
        content_type = (upload.content_type or "application/octet-stream")[:100]
        blobs.append(
            CalibrationRunFile(
                position=position,
                filename=name,
                content_type=content_type.replace("\x00", ""),
                size=len(data),
                data=data,
            )
        )
    if size is None:
        raise FieldProblem(422, "files", "upload at least one image", "form")
    _check_image_size(session, camera_id, size, "files", "form")

    run = CalibrationRun(
        kind="intrinsics",
        source="images",
        camera_id=camera_id,
        inputs={"chessboard": [cols, rows], "square_m": square, "image_size": list(size)},
        options={"skew": skew, "distortion": distortion},
        files=blobs,
    )
    return _queue(session, executor, run)


@router.get("", response_model=Page[CalibrationRunRead], dependencies=[ReadAccess])
def list_calibration_runs(
    session: SessionDep,
    page: PageDep,
    camera_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    status: Annotated[RunStatus | None, Query()] = None,
):
    """Return a page of runs, newest first, optionally of one camera or one status."""
    stmt = select(CalibrationRun).order_by(CalibrationRun.id.desc())
    if camera_id is not None:
        stmt = stmt.where(CalibrationRun.camera_id == camera_id)
    if status is not None:
        stmt = stmt.where(CalibrationRun.status == status)
    return paginate(session, stmt, page)


@router.get("/{run_id}", response_model=CalibrationRunRead, dependencies=[ReadAccess])
def get_calibration_run(run_id: RunId, session: SessionDep):
    """Return a run: its status, and its result or error once finished."""
    return get_or_404(session, CalibrationRun, run_id, "calibration run")


@router.post(
    "/{run_id}/apply",
    response_model=CameraRead | list[CameraRead] | ArmRead | ProjectorRead,
    dependencies=[WriteAccess],
)
def apply_calibration_run(run_id: RunId, session: SessionDep, scene: SceneDep):
    """Set the camera's intrinsics from a successful run and record it in the camera's
    calibration history; return the updated camera. Applying the run the camera already has
    changes nothing and adds no history entry. A network run sets intrinsics and pose of
    every camera it calibrated and returns the list of them. A hand-eye run sets its arm's
    T_ee_camera, records it in the arm's hand-eye history and returns the arm. A projector run
    sets the projector's pose, records it in its history and returns the projector. A
    placement run sets its camera's pose (and K when it estimated it) and returns the camera."""
    run = get_or_404(session, CalibrationRun, run_id, "calibration run")
    if run.status != RUN_SUCCEEDED or run.result is None:
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail=f"run {run_id} is {run.status}; only a succeeded run can be applied",
        )
    if run.kind == "hand-eye":
        return apply_hand_eye_run(run, session)
    if run.kind == "projector":
        return apply_projector_run(run, session, scene)
    if run.kind == "network":
        return _apply_network(run, session, scene)
    if run.kind == "placement":
        return apply_placement(run, session, scene)
    if run.camera_id is None:
        raise HTTPException(
            status.HTTP_409_CONFLICT, detail=f"the camera of run {run_id} was deleted"
        )
    camera = get_or_404(session, Camera, run.camera_id, "camera")
    width, height = run.result["image_size"]
    if (width, height) != (camera.width, camera.height):
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail=f"run {run_id} calibrated {width}x{height} images but camera {camera.id} is "
            f"{camera.width}x{camera.height}; fix the camera's size or calibrate again",
        )
    values = {"K": run.result["K"], "dist": run.result["dist"]}
    if _set_calibration(session, camera.id, run.id, values):
        session.add(
            CameraCalibration(
                camera_id=camera.id,
                calibration_run_id=run.id,
                K=run.result["K"],
                dist=run.result["dist"],
                rms=run.result.get("rms"),
                image_width=width,
                image_height=height,
            )
        )
        session.commit()
        session.refresh(camera)
        scene.camera_changed(camera)
    return camera


def apply_placement(run: CalibrationRun, session, scene) -> Camera:
    """Set a camera's pose (and K and distortion when the run estimated them) from a
    placement run, recording it in the camera's calibration history; applying the run the
    camera already has changes nothing."""
    assert run.result is not None
    if run.camera_id is None:
        raise HTTPException(
            status.HTTP_409_CONFLICT, detail=f"the camera of run {run.id} was deleted"
        )
    camera = get_or_404(session, Camera, run.camera_id, "camera")
    width, height = run.result["image_size"]
    if (width, height) != (camera.width, camera.height):
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail=f"run {run.id} placed a {width}x{height} camera but camera {camera.id} is "
            f"{camera.width}x{camera.height}; place it again",
        )
    values = placement_values(run.result)
    if _set_calibration(session, camera.id, run.id, values):
        session.add(
            CameraCalibration(
                camera_id=camera.id,
                calibration_run_id=run.id,
                K=values.get("K", camera.K),
                dist=values.get("dist", camera.dist or [0.0] * 5),
                rms=run.result.get("rms"),
                image_width=width,
                image_height=height,
            )
        )
        session.commit()
        session.refresh(camera)
        scene.camera_changed(camera)
    return camera


def _set_calibration(session, camera_id: int, run_id: int, values: dict) -> bool:
    """Set a camera's calibration from run `run_id` unless it is already that run's; return
    whether it changed. One conditional UPDATE, so two concurrent applies of one run change
    the camera (and add to its history) once: applying is idempotent."""
    result = session.execute(
        update(Camera)
        .where(
            Camera.id == camera_id,
            or_(Camera.calibration_run_id.is_(None), Camera.calibration_run_id != run_id),
        )
        .values(status="calibrated", calibration_run_id=run_id, updated_at=utcnow(), **values)
        .execution_options(synchronize_session=False)
    )
    return result.rowcount == 1


def _apply_network(run: CalibrationRun, session, scene) -> list[Camera]:
    cameras, changed = [], []
    for result in run.result["cameras"] if run.result else []:
        camera = session.get(Camera, result.get("camera_id") or 0)
        if camera is None:
            continue  # deleted since the run
        cameras.append(camera)
        values = {k: result[k] for k in ("K", "dist", "T_world_camera")}
        if not _set_calibration(session, camera.id, run.id, values):
            continue  # applied already
        changed.append(camera)
        width, height = result["image_size"]
        session.add(
            CameraCalibration(
                camera_id=camera.id,
                calibration_run_id=run.id,
                K=result["K"],
                dist=result["dist"],
                rms=result["rms"],
                image_width=width,
                image_height=height,
            )
        )
    if not cameras:
        raise HTTPException(
            status.HTTP_409_CONFLICT, detail=f"the cameras of run {run.id} were all deleted"
        )
    session.commit()
    for camera in cameras:
        session.refresh(camera)
    for camera in changed:
        scene.camera_changed(camera)
    return cameras
