"""Landmarks: printed markers with their payload, physical size and world pose when known;
their printable artwork at true size, and the detection of landmarks in an uploaded image."""

from __future__ import annotations

import json
from typing import Annotated, Any

import cv2
import numpy as np
from fastapi import APIRouter, File, Form, Path, Query, UploadFile, status
from fastapi.responses import Response
from sqlalchemy import select

from core.errors import InvalidInput
from core.landmarks import detect_landmarks
from core.landmarks.artwork import to_pdf, to_png, to_svg
from server.api._crud import (
    Unassigned,
    apply_changes,
    check_references,
    get_or_404,
    in_space,
    paginate,
)
from server.api.deps import PageDep, ReadAccess, SceneDep, SessionDep, SettingsDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.api.limits import check_image_size
from server.db.models import Camera, Landmark, Space
from server.schemas.common import MAX_ID, Page
from server.schemas.landmarks import DetectResult
from server.schemas.registry import LandmarkCreate, LandmarkKind, LandmarkRead, LandmarkUpdate
from server.services.calibration import decode_image
from server.services.landmarks import LandmarkUnusable, detection_read, landmark_artwork

# A PNG is drawn at 4x in each direction before it is reduced: 2e6 output pixels cost ~100 MB
# while drawn (a 20 cm signpost at the default 5000 px/m is 1.7e6).
MAX_PRINT_PIXELS = 2_000_000

router = APIRouter(prefix="/landmarks", tags=["landmarks"], responses=PROBLEM_RESPONSES)
LandmarkId = Annotated[int, Path(ge=1, le=MAX_ID)]


@router.get("", response_model=Page[LandmarkRead], dependencies=[ReadAccess])
def list_landmarks(
    session: SessionDep,
    page: PageDep,
    space_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    unassigned: Unassigned = False,
    kind: Annotated[LandmarkKind | None, Query()] = None,
):
    """Return a page of landmarks, optionally of one space (and those of no space) or one
    kind."""
    stmt = select(Landmark).order_by(Landmark.id)
    stmt = in_space(stmt, Landmark.space_id, space_id, unassigned)
    if kind is not None:
        stmt = stmt.where(Landmark.kind == kind)
    return paginate(session, stmt, page)


@router.post(
    "",
    response_model=LandmarkRead,
    status_code=status.HTTP_201_CREATED,
    dependencies=[WriteAccess],
)
def create_landmark(body: LandmarkCreate, session: SessionDep, scene: SceneDep):
    """Create a landmark."""
    check_references(session, {"space_id": (Space, body.space_id)})
    landmark = Landmark(**body.model_dump())
    session.add(landmark)
    session.commit()
    scene.landmarks_changed(session)
    return landmark


@router.get("/{landmark_id}", response_model=LandmarkRead, dependencies=[ReadAccess])
def get_landmark(landmark_id: LandmarkId, session: SessionDep):
    """Return one landmark."""
    return get_or_404(session, Landmark, landmark_id, "landmark")


@router.patch("/{landmark_id}", response_model=LandmarkRead, dependencies=[WriteAccess])
def update_landmark(
    landmark_id: LandmarkId, body: LandmarkUpdate, session: SessionDep, scene: SceneDep
):
    """Change the fields given (null clears an optional one)."""
    landmark = get_or_404(session, Landmark, landmark_id, "landmark")
    changes = body.model_dump(exclude_unset=True)
    check_references(session, {"space_id": (Space, changes.get("space_id"))})
    apply_changes(landmark, changes)
    session.commit()
    scene.landmarks_changed(session)
    return landmark


@router.delete("/{landmark_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess])
def delete_landmark(landmark_id: LandmarkId, session: SessionDep, scene: SceneDep) -> None:
    """Delete a landmark."""
    session.delete(get_or_404(session, Landmark, landmark_id, "landmark"))
    session.commit()
    scene.landmarks_changed(session)


def _artwork(session, landmark_id: int):
    landmark = get_or_404(session, Landmark, landmark_id, "landmark")
    try:
        return landmark, landmark_artwork(landmark)
    except LandmarkUnusable as exc:
        raise FieldProblem(422, exc.field, exc.reason, "landmark") from None


def _attachment(landmark: Landmark, ext: str) -> dict[str, str]:
    return {"Content-Disposition": f'inline; filename="landmark-{landmark.id}.{ext}"'}


@router.get(
    "/{landmark_id}/print.svg",
    dependencies=[ReadAccess],
    responses={200: {"content": {"image/svg+xml": {}}}},
)
def print_svg(landmark_id: LandmarkId, session: SessionDep) -> Response:
    """Return the landmark's artwork as SVG at true size (width and height in mm): the QR
    symbol of its payload in a blue frame (object mark) or red rings (signpost), of side or
    outer diameter size_m, with its id and name under it. 422 when the landmark is not a QR
    landmark or its payload is not a landmark payload (the reason named)."""
    landmark, art = _artwork(session, landmark_id)
    return Response(to_svg(art), media_type="image/svg+xml", headers=_attachment(landmark, "svg"))


@router.get(
    "/{landmark_id}/print.pdf",
    dependencies=[ReadAccess],
    responses={200: {"content": {"application/pdf": {}}}},
)
def print_pdf(landmark_id: LandmarkId, session: SessionDep) -> Response:
    """Return the landmark's artwork as a one-page PDF whose page is the artwork's true size."""
    landmark, art = _artwork(session, landmark_id)
    return Response(to_pdf(art), media_type="application/pdf", headers=_attachment(landmark, "pdf"))


@router.get(
    "/{landmark_id}/print.png",
    dependencies=[ReadAccess],
    responses={200: {"content": {"image/png": {}}}},
)
def print_png(
    landmark_id: LandmarkId,
    session: SessionDep,
    pixels_per_metre: Annotated[
        float, Query(ge=500, le=40_000, description="Resolution; 5000 px/m = 127 dpi.")
    ] = 5000.0,
) -> Response:
    """Return the landmark's artwork as PNG (its resolution in the pHYs chunk, so it prints at
    true size)."""
    landmark, art = _artwork(session, landmark_id)
    ppmm = pixels_per_metre / 1000.0
    pixels = round(art.page_mm[0] * ppmm) * round(art.page_mm[1] * ppmm)
    if pixels > MAX_PRINT_PIXELS:
        raise FieldProblem(
            422,
            "pixels_per_metre",
            f"a {art.size} m landmark at {pixels_per_metre:g} px/m is a {pixels}-pixel PNG, over "
            f"the limit of {MAX_PRINT_PIXELS}; lower pixels_per_metre or print the SVG or PDF",
            "query",
        )
    png = to_png(art, pixels_per_metre)
    return Response(png, media_type="image/png", headers=_attachment(landmark, "png"))


def _json_matrix(text: str | None, field: str, shapes: tuple[tuple[int, ...], ...]) -> Any:
    if text is None:
        return None
    try:
        value = np.asarray(json.loads(text), dtype=float)
    except (ValueError, TypeError, RecursionError):
        raise FieldProblem(
            422, field, f"{field} must be a JSON array of numbers of shape {shapes}", "form"
        ) from None
    if value.shape not in shapes or not np.all(np.isfinite(value)):
        raise FieldProblem(
            422,
            field,
            f"{field} must be finite numbers of shape {shapes}, got {value.shape}",
            "form",
        )
    return value


def _camera_model(
    session, camera_id: int | None, K: str | None, dist: str | None, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray | None]:
    if (camera_id is None) == (K is None):
        raise FieldProblem(
            422,
            "camera_id",
            "give either camera_id (a registered camera with intrinsics) or K (a JSON 3x3 "
            "matrix) with optional dist",
            "form",
        )
    if camera_id is not None:
        if dist is not None:
            raise FieldProblem(
                422, "dist", "dist comes from the camera; give it only with K", "form"
            )
        camera = get_or_404(session, Camera, camera_id, "camera")
        if camera.K is None:
            raise FieldProblem(
                409,
                "camera_id",
                f"camera {camera_id} has no intrinsics K; calibrate it first (POST "
                "/calibration-runs) or send K",
                "form",
            )
        if (camera.width, camera.height) != size:
            raise FieldProblem(
                409,
                "image",
                f"the image is {size[0]}x{size[1]} but camera {camera_id} is calibrated at "
                f"{camera.width}x{camera.height}; send an image of the camera's size",
                "form",
            )
        return np.asarray(camera.K, float), (
            None if camera.dist is None else np.asarray(camera.dist, float)
        )
    Km = _json_matrix(K, "K", ((3, 3),))
    d = _json_matrix(dist, "dist", ((4,), (5,), (8,), (12,), (14,)))
    return Km, d


@router.post("/detect", response_model=DetectResult, dependencies=[WriteAccess])
def detect(
    session: SessionDep,
    settings: SettingsDep,
    image: Annotated[UploadFile, File(description="A photo (PNG, JPEG, ...).")],
    camera_id: Annotated[int | None, Form(ge=1, le=MAX_ID)] = None,
    K: Annotated[str | None, Form(max_length=1000, description="JSON 3x3 intrinsics.")] = None,
    dist: Annotated[
        str | None, Form(max_length=1000, description="JSON OpenCV distortion (with K).")
    ] = None,
    frame_size: Annotated[
        float, Form(ge=0.005, le=5.0, allow_inf_nan=False, description="Blue frame side, m.")
    ] = 0.10,
    ring_size: Annotated[
        float, Form(ge=0.005, le=5.0, allow_inf_nan=False, description="Outer ring diameter, m.")
    ] = 0.20,
):
    """Return the object marks and signposts found in an uploaded photo: kind, outline
    (pixels), pose T_cam_mark with its 6x6 covariance (rotation vector, translation), and the
    decoded payload or the reason it could not be read (core.landmarks.detect_landmarks).
    The camera is a registered one with intrinsics (camera_id) or given by K and dist."""
    name = (image.filename or "image").replace("\x00", "")[-255:]
    data = image.file.read(settings.max_upload_file_bytes + 1)
    if len(data) > settings.max_upload_file_bytes:
        raise FieldProblem(
            413, "image", f"{name!r} exceeds {settings.max_upload_file_bytes} bytes", "form"
        )
    header = check_image_size(data, settings.max_image_pixels, "image", name)
    Km, d = _camera_model(session, camera_id, K, dist, (header.width, header.height))
    picture = decode_image(data, settings.max_image_pixels)
    if picture is None:
        raise FieldProblem(415, "image", f"{name!r} is not an image OpenCV can decode", "form")
    if picture.ndim == 2:
        picture = cv2.cvtColor(picture, cv2.COLOR_GRAY2BGR)
    try:
        found = detect_landmarks(picture, Km, d, frame_size=frame_size, ring_size=ring_size)
    except InvalidInput as exc:
        field = "K" if camera_id is None else "camera_id"
        raise FieldProblem(422, field, f"the camera model cannot be used: {exc}", "form") from None
    return DetectResult(
        width=int(picture.shape[1]),
        height=int(picture.shape[0]),
        camera_id=camera_id,
        frame_size=frame_size,
        ring_size=ring_size,
        detections=[detection_read(det) for det in found],
    )
