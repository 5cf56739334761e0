"""Calibration runs: submitted (202), executed off the event loop, read back, applied."""

from __future__ import annotations

import re
from typing import Annotated

from fastapi import (
    APIRouter,
    File,
    Form,
    HTTPException,
    Path,
    Query,
    UploadFile,
    status,
)
from fastapi.responses import JSONResponse
from pydantic import Field
from sqlalchemy import select
from starlette.requests import Request

from server.api._crud import check_references, get_or_404, paginate
from server.api.deps import (
    ExecutorDep,
    PageDep,
    ReadAccess,
    SceneDep,
    SessionDep,
    SettingsDep,
    TwinDep,
    WriteAccess,
)
from server.api.errors import PROBLEM_RESPONSES, FieldProblem, problem_response
from server.api.limits import check_image_size
from server.db.models import RUN_SUCCEEDED, CalibrationRun, CalibrationRunFile, Camera
from server.schemas.calibration import (
    CalibrationRunRead,
    DistortionModel,
    IntrinsicsRunCreate,
    RunStatus,
    implausible_square,
)
from server.schemas.common import MAX_ID, FieldError, Page
from server.schemas.manipulation import ArmRead, HandEyeRunCreate
from server.schemas.paths import ProjectorRunCreate
from server.schemas.registry import CameraRead, ProjectorRead
from server.schemas.twin import NetworkRunCreate
from server.services.calibration import RunContext, RunRefused, decode_image, intrinsics, kind_of
from server.services.runs import queue_run

router = APIRouter(
    prefix="/calibration-runs", tags=["calibration runs"], responses=PROBLEM_RESPONSES
)
RunId = Annotated[int, Path(ge=1, le=MAX_ID)]
_PATTERN = re.compile(r"^\s*(\d{1,3})\s*[xX]\s*(\d{1,3})\s*$")


async def answer_refused(request: Request, exc: Exception) -> JSONResponse:
    """Answer a run that cannot be created or applied (RunRefused) as problem details, naming
    the field at fault when there is one."""
    del request
    assert isinstance(exc, RunRefused)
    errors = None
    if exc.field is not None:
        errors = [FieldError(field=exc.field, location=exc.location, reason=str(exc))]
    return problem_response(exc.status, str(exc), errors)


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
    twin: TwinDep,
    settings: SettingsDep,
):
    """Queue a calibration; poll GET /calibration-runs/{id}. Kind "intrinsics": Zhang's method
    on point correspondences of one camera. Kind "network": the twin's calibration drive (the
    robot's marker driven over the floor) calibrates every twin camera, intrinsics and pose.
    Kind "hand-eye": an arm's eye-in-hand camera, on the twin or from uploaded pose pairs.
    Kind "projector": the twin's projector's mount, from spots the ceiling cameras locate."""
    create = kind_of(body.kind).create
    assert create is not None  # every kind of the body's union is created here
    run = create(body, RunContext(session, twin, settings.twin_seed))
    return queue_run(session, run, executor)


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
    run = intrinsics.create_from_images(
        session,
        camera_id,
        blobs,
        size,
        (cols, rows),
        square,
        {"skew": skew, "distortion": distortion},
    )
    return queue_run(session, run, executor)


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
    return kind_of(run.kind).apply(session, run, scene)
