"""`GET /spaces/{id}/export.mcap`: a time range of a space as MCAP (Foxglove's schemas)."""

from __future__ import annotations

import time
from typing import Annotated

import cv2
from fastapi import APIRouter, Path, Query
from fastapi.responses import StreamingResponse

from server.api._crud import get_or_404
from server.api.deps import ReadAccess, SessionDep, SessionFactoryDep, SettingsDep, TwinDep
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.db.models import Space
from server.schemas.common import MAX_ID
from server.services.export import (
    LatestImage,
    check_range,
    export_messages,
    mcap_stream,
)
from server.services.twin import Twin

router = APIRouter(tags=["export"], responses=PROBLEM_RESPONSES)

_JPEG_QUALITY = 90


def _latest_images(twin: Twin | None, space_id: int) -> list[LatestImage]:
    """Return the newest frame of each of the twin's cameras in `space_id` (none without the
    twin: the service keeps no images of real cameras)."""
    if twin is None or twin.space_id != space_id:
        return []
    images = []
    for camera_id in twin.camera_ids.values():
        frame = twin.frame(camera_id)
        if frame is None:
            continue
        ok, buf = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, _JPEG_QUALITY])
        if ok:
            images.append(LatestImage(camera_id, float(frame.t), buf.tobytes()))
    return images


@router.get(
    "/spaces/{space_id}/export.mcap",
    dependencies=[ReadAccess],
    response_class=StreamingResponse,
    responses={
        200: {
            "content": {"application/octet-stream": {}},
            "description": "An MCAP file (JSON messages, foxglove.* JSON schemas).",
        }
    },
)
def export_mcap(
    space_id: Annotated[int, Path(ge=1, le=MAX_ID)],
    session: SessionDep,
    settings: SettingsDep,
    twin: TwinDep,
    factory: SessionFactoryDep,
    since: Annotated[float, Query(description="Start, Unix seconds (service clock).")],
    until: Annotated[float | None, Query(description="End, Unix seconds; default: now.")] = None,
) -> StreamingResponse:
    """Export the space's detections, tracks (track points), robot poses, camera
    calibrations and the latest twin camera images between `since` and `until` as an MCAP
    file with Foxglove's well-known schemas, streamed as it is written. A range longer than
    INTSPACE_EXPORT_MAX_RANGE_S (default an hour) is refused with 422."""
    end = time.time() if until is None else until
    limit = settings.export_max_range_s
    why = check_range(since, end, limit)
    if why is not None:
        field = "since" if "since" in why.split(" ")[:1] else "until"
        raise FieldProblem(422, field, why, "query")
    get_or_404(session, Space, space_id, "space")
    images = _latest_images(twin, space_id)

    def chunks():
        # Its own session: the request's closes when the endpoint returns, before streaming.
        with factory() as own:
            messages = export_messages(own, space_id, since, end, images)
            yield from mcap_stream(
                messages,
                metadata={"space_id": str(space_id), "since": repr(since), "until": repr(end)},
            )

    name = f"space-{space_id}-{since:.0f}-{end:.0f}.mcap"
    return StreamingResponse(
        chunks(),
        media_type="application/octet-stream",
        headers={
            "Content-Disposition": f'attachment; filename="{name}"',
            "Cache-Control": "no-store",
        },
    )
