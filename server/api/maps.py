"""Maps of the space: the coverage-and-accuracy map of the camera network (JSON or PNG).

The map honours occlusion by the home's walls and furniture when the space is the digital
twin's home (its floor plan is the twin scene's); other spaces have no floor plan in the
registry yet, so their map counts every camera that images a cell.
"""

from __future__ import annotations

from typing import Annotated, Literal

import cv2
import numpy as np
from fastapi import APIRouter, HTTPException, Query, status
from fastapi.responses import JSONResponse, Response
from sqlalchemy import select
from sqlalchemy.orm import Session

from core.errors import IntspaceError
from core.localization import coverage_map
from core.localization.cameras import NetworkCamera
from core.sim.occluders import scene_occluders
from server.api.deps import ReadAccess, SessionDep, TwinDep
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Camera, Room, Space
from server.schemas.common import MAX_ID
from server.services.cameras import CameraNotPlaced, network_camera
from server.services.floor_plan import twin_scene_of

# Caps that keep one map's memory well under 150 MB (measured on `intspace serve`: the
# projections and Jacobians cost ~0.5 kB per camera and cell, the JSON lists ~0.2 kB per cell,
# the PNG ~10 bytes per pixel while it is drawn and encoded).
MAX_CELLS = 100_000
MAX_CAMERA_CELLS = 400_000
MAX_PNG_PIXELS = 6_000_000

router = APIRouter(prefix="/maps", tags=["maps"], responses=PROBLEM_RESPONSES)


def usable_cameras(
    session: Session, space_id: int, bounds: tuple[tuple[float, float], tuple[float, float]]
) -> tuple[dict[int, NetworkCamera], dict[int, str]]:
    """Return the cameras of the space the coverage map can use, and the reason each other one
    cannot be used: one bad device is reported, never the end of the whole read. Each camera
    is tried alone on a 2 x 2 map of `bounds` ((x0, x1), (y0, y1)) first, so that a model whose
    numbers overflow (fx = 1e-300) fails there, alone."""
    usable: dict[int, NetworkCamera] = {}
    refused: dict[int, str] = {}
    rows = session.scalars(select(Camera).where(Camera.space_id == space_id).order_by(Camera.id))
    (x0, x1), (y0, y1) = bounds
    for camera in rows:
        try:
            network = network_camera(camera)
            with np.errstate(over="raise", invalid="raise", divide="raise"):
                coverage_map([network], (x0, x1), (y0, y1), spacing=max(x1 - x0, y1 - y0) / 2)
        except CameraNotPlaced as exc:
            refused[camera.id] = f"no {exc.missing}"
            continue
        except (IntspaceError, ArithmeticError, ValueError, TypeError) as exc:
            refused[camera.id] = f"unusable camera model: {type(exc).__name__}: {exc}"
            continue
        usable[camera.id] = network
    return usable, refused


@router.get(
    "/coverage",
    dependencies=[ReadAccess],
    responses={200: {"content": {"application/json": {}, "image/png": {}}}},
)
def get_coverage(
    session: SessionDep,
    twin: TwinDep,
    space_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    spacing: Annotated[float, Query(ge=0.02, le=5.0, description="Cell size, metres.")] = 0.1,
    height: Annotated[float, Query(ge=0.0, le=5.0, description="Plane Z, metres.")] = 0.0,
    pixel_sigma: Annotated[float, Query(gt=0, le=100, description="Detection noise, px.")] = 1.0,
    format: Annotated[Literal["json", "png"], Query()] = "json",
    scale: Annotated[int, Query(ge=1, le=40, description="PNG pixels per cell.")] = 8,
    max_std: Annotated[
        float | None,
        Query(gt=0, le=100, description="PNG colour scale's upper end, metres of CRB std."),
    ] = None,
) -> Response:
    """Return, over the floor bounds of the space's rooms, how many posed cameras see each cell
    and the Cramer-Rao standard deviation of a position there (core.localization.coverage_map).

    A camera counts for a cell only when nothing stands between them: in the digital twin's
    home its walls (with their doors) and furniture hide the floor behind them. JSON (with
    `fraction_hidden`, the share of the (camera, cell) pairs in a camera's image that an
    occluder hides, `occlusion` naming the floor plan used or null, and `occluders`, their
    footprints), or a PNG floor plan: the heat map (bright = accurate, black = unseen, a grey
    dot where only one camera sees), the walls in white, furniture outlined, and on the right
    the colour scale in metres of CRB std and the legend."""
    if space_id is None:
        space_id = session.scalar(select(Space.id).order_by(Space.id).limit(1))
        if space_id is None:
            raise HTTPException(status.HTTP_409_CONFLICT, detail="the registry has no space yet")
    elif session.get(Space, space_id) is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no space with id {space_id}")
    polygons = session.scalars(select(Room.polygon).where(Room.space_id == space_id)).all()
    points = [p for polygon in polygons for p in polygon]
    if not points:
        raise HTTPException(
            status.HTTP_409_CONFLICT, detail=f"space {space_id} has no rooms to bound the floor"
        )
    lo, hi = np.min(points, axis=0), np.max(points, axis=0)
    bounds = ((float(lo[0]), float(hi[0])), (float(lo[1]), float(hi[1])))
    cameras, refused = usable_cameras(session, space_id, bounds)
    if not cameras:
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail=f"space {space_id} has no usable camera (intrinsics and a pose)"
            + "".join(f"; camera {cid}: {why}" for cid, why in refused.items()),
        )
    nx = max(1, round((hi[0] - lo[0]) / spacing))
    ny = max(1, round((hi[1] - lo[1]) / spacing))
    cells = nx * ny
    if cells > MAX_CELLS or cells * len(cameras) > MAX_CAMERA_CELLS:
        raise HTTPException(
            status.HTTP_422_UNPROCESSABLE_ENTITY,
            detail=f"spacing {spacing} m gives {nx} x {ny} = {cells} cells for {len(cameras)} "
            f"camera(s), over the limit of {MAX_CELLS} cells and {MAX_CAMERA_CELLS} "
            "camera-cells; use a larger spacing",
        )
    if format == "png" and cells * scale**2 > MAX_PNG_PIXELS:
        raise HTTPException(
            status.HTTP_422_UNPROCESSABLE_ENTITY,
            detail=f"a {nx} x {ny}-cell map at scale {scale} is a {nx * scale} x {ny * scale} "
            f"= {cells * scale**2} pixel PNG, over the limit of {MAX_PNG_PIXELS} pixels; use "
            "a larger spacing or a smaller scale",
        )
    # The twin scene whose walls and furniture stand in the space, or None.
    plan = twin_scene_of(twin, session, space_id)
    cov = coverage_map(
        list(cameras.values()),
        (float(lo[0]), float(hi[0])),
        (float(lo[1]), float(hi[1])),
        spacing=spacing,
        height=height,
        pixel_sigma=pixel_sigma,
        occluders=None if plan is None else scene_occluders(plan),
    )
    if format == "png":
        _, png = cv2.imencode(".png", cov.plan_image(scale, max_std=max_std))
        return Response(png.tobytes(), media_type="image/png")
    body = cov.to_dict()
    body.pop("seen_by")
    body["occlusion"] = None if plan is None else f"twin scene {plan.name!r}"
    body["space_id"] = space_id
    body["camera_ids"] = list(cameras)
    body["cameras_refused"] = {str(cid): why for cid, why in refused.items()}
    body["fraction_covered"] = {"1": cov.fraction_covered(1), "2": cov.fraction_covered(2)}
    return JSONResponse(body)
