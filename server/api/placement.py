"""Placing a real camera: its latest image from its node, and its pose from floor points.

PUT /cameras/{id}/frame takes the camera node's JPEG (at most one a second per camera, of the
camera's registered size), served by GET /cameras/{id}/frame.jpg; POST /cameras/{id}/placement
fits the camera's pose (and focal length when unknown) to clicked floor points and stores the
result as a calibration run of kind "placement", applied at once or later by
POST /calibration-runs/{id}/apply.
"""

from __future__ import annotations

import math
from typing import Annotated

import cv2
import numpy as np
from fastapi import APIRouter, Body, Depends, HTTPException, Path, Response, status

from server.api._crud import get_or_404
from server.api.deps import FramesDep, SceneDep, SessionDep, SettingsDep, WriteAccess, require_write
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.api.limits import MiB, read_image_header
from server.db.models import Camera
from server.schemas.calibration import PlacementCreate, PlacementRead
from server.schemas.common import MAX_ID
from server.services.auth import Principal
from server.services.calibration import placement

router = APIRouter(prefix="/cameras", tags=["cameras"], responses=PROBLEM_RESPONSES)
CameraId = Annotated[int, Path(ge=1, le=MAX_ID)]
# A camera's JPEG frame, at most (bytes): a 4K frame at quality 95 is ~3 MB.
MAX_FRAME_BYTES = 4 * MiB


@router.post(
    "/{camera_id}/placement",
    status_code=status.HTTP_201_CREATED,
    response_model=PlacementRead,
    dependencies=[WriteAccess],
)
def place_camera_from_points(
    camera_id: CameraId, body: PlacementCreate, session: SessionDep, scene: SceneDep
):
    """Fit the camera's pose (and focal length when it has no intrinsics: square pixels,
    centred principal point, no distortion) to >= 4 pixels whose floor positions are known;
    a wrong pair is found and left out when there are 6 or more. Store it as a calibration
    run of kind "placement"; `apply` sets the camera at once, otherwise apply the run with
    POST /calibration-runs/{run_id}/apply. Answers the run id, the camera's T_world_camera
    and K, every point's residual (pixels), the rejected points and standard deviations.
    Degenerate points (on a line, at one spot, a view that fixes no focal length) -> 422."""
    camera = get_or_404(session, Camera, camera_id, "camera")
    run = placement.create(body, camera)
    session.add(run)
    session.commit()
    if body.apply:
        placement.apply(session, run, scene)
    result = placement.Result.model_validate(run.result)
    return PlacementRead(
        run_id=run.id,
        applied=body.apply,
        T_world_camera=result.T_world_camera,
        K=result.K,
        dist=result.dist,
        f_estimated=result.f_estimated,
        residuals_px=result.residuals_px,
        residuals=result.residuals,
        rejected=result.rejected,
        rms=result.rms,
        std=result.std,
    )


@router.put(
    "/{camera_id}/frame",
    status_code=status.HTTP_204_NO_CONTENT,
    response_class=Response,
    openapi_extra={
        "requestBody": {"content": {"image/jpeg": {"schema": {"type": "string"}}}, "required": True}
    },
)
def put_camera_frame(
    camera_id: CameraId,
    session: SessionDep,
    settings: SettingsDep,
    frames: FramesDep,
    who: Annotated[Principal | None, Depends(require_write)],
    body: Annotated[bytes, Body(media_type="image/jpeg")],
) -> Response:
    """Keep the camera's latest image (a JPEG of the camera's width x height, from its node;
    an ingest token speaking for the camera, or a write token), served by
    GET /cameras/{id}/frame.jpg. At most one frame a second per camera: 429 with Retry-After
    beyond."""
    del who  # an ingest token for another camera was refused by require_write
    camera = get_or_404(session, Camera, camera_id, "camera")
    wait = frames.wait_s(camera_id)
    if wait > 0:
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            detail=f"camera {camera_id} sent a frame {1 - wait:.2f} s ago; at most one a second",
            headers={"Retry-After": str(max(1, math.ceil(wait)))},
        )
    if len(body) > MAX_FRAME_BYTES:
        raise FieldProblem(413, "body", f"a frame is at most {MAX_FRAME_BYTES} bytes")
    header = read_image_header(body)
    if header is None or header.format != "JPEG":
        raise FieldProblem(415, "body", "send the frame as a JPEG (Content-Type: image/jpeg)")
    if (header.width, header.height) != (camera.width, camera.height):
        raise FieldProblem(
            422,
            "body",
            f"the frame is {header.width}x{header.height} but camera {camera_id} is "
            f"{camera.width}x{camera.height}; send the camera's own frames or fix its size",
        )
    if header.pixels > settings.max_image_pixels:
        raise FieldProblem(413, "body", "the frame has more pixels than INTSPACE_MAX_IMAGE_PIXELS")
    image = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR)
    if image is None or image.shape[1] != camera.width or image.shape[0] != camera.height:
        raise FieldProblem(422, "body", "the JPEG could not be decoded; send a whole frame")
    wait = frames.put(camera_id, bytes(body))
    if wait > 0:  # another upload of the camera came in while this one was checked
        raise HTTPException(
            status.HTTP_429_TOO_MANY_REQUESTS,
            detail=f"camera {camera_id}: at most one frame a second",
            headers={"Retry-After": str(max(1, math.ceil(wait)))},
        )
    return Response(status_code=status.HTTP_204_NO_CONTENT)
