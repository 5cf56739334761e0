"""Maps of the space: the coverage-and-accuracy map of the camera network (JSON or PNG)."""

from __future__ import annotations

from typing import Annotated, Literal

import cv2
import numpy as np
from fastapi import APIRouter, HTTPException, Query, status
from fastapi.responses import JSONResponse, Response
from sqlalchemy import select

from core.localization import coverage_map
from server.api.deps import ReadAccess, SessionDep
from server.api.errors import PROBLEM_RESPONSES
from server.db.models import Camera, Room, Space
from server.schemas.common import MAX_ID
from server.services.twin import registry_cameras

router = APIRouter(prefix="/maps", tags=["maps"], responses=PROBLEM_RESPONSES)


@router.get(
    "/coverage",
    dependencies=[ReadAccess],
    responses={200: {"content": {"application/json": {}, "image/png": {}}}},
)
def get_coverage(
    session: SessionDep,
    space_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    spacing: Annotated[float, Query(ge=0.02, le=5.0, description="Cell size, metres.")] = 0.1,
    height: Annotated[float, Query(ge=0.0, le=5.0, description="Plane Z, metres.")] = 0.0,
    pixel_sigma: Annotated[float, Query(gt=0, le=100, description="Detection noise, px.")] = 1.0,
    format: Annotated[Literal["json", "png"], Query()] = "json",
    scale: Annotated[int, Query(ge=1, le=40, description="PNG pixels per cell.")] = 8,
) -> Response:
    """Return, over the floor bounds of the space's rooms, how many posed cameras see each cell
    and the Cramer-Rao standard deviation of a position there (core.localization.coverage_map);
    JSON, or a heat map PNG (bright = accurate, black = unseen)."""
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
    ids = list(session.scalars(select(Camera.id).where(Camera.space_id == space_id)))
    cameras, _ = registry_cameras(session, ids)
    if not cameras:
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail=f"space {space_id} has no camera with intrinsics and a pose",
        )
    lo, hi = np.min(points, axis=0), np.max(points, axis=0)
    cells = ((hi[0] - lo[0]) / spacing) * ((hi[1] - lo[1]) / spacing)
    if cells > 1_000_000:
        raise HTTPException(
            status.HTTP_422_UNPROCESSABLE_ENTITY,
            detail=f"spacing {spacing} m gives {cells:.0f} cells; use a larger spacing",
        )
    cov = coverage_map(
        list(cameras.values()),
        (float(lo[0]), float(hi[0])),
        (float(lo[1]), float(hi[1])),
        spacing=spacing,
        height=height,
        pixel_sigma=pixel_sigma,
    )
    if format == "png":
        img = cov.heatmap()
        # Rows are y growing downwards; flip so that +y points up as on a floor plan.
        img = cv2.resize(img[::-1], None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        _, png = cv2.imencode(".png", img)
        return Response(png.tobytes(), media_type="image/png")
    body = cov.to_dict()
    body.pop("seen_by")
    body["space_id"] = space_id
    body["camera_ids"] = list(cameras)
    body["fraction_covered"] = {"1": cov.fraction_covered(1), "2": cov.fraction_covered(2)}
    return JSONResponse(body)
