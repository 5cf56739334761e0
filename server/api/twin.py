"""Control of the digital twin (state, pause, resume, reset, rate, scenarios) and the latest
frame of its cameras."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated

import cv2
from fastapi import APIRouter, HTTPException, Path, Query, status
from fastapi.responses import Response

from core.sim.scenarios import DESCRIPTIONS, SCENARIOS
from server.api.deps import FramesDep, ReadAccess, TwinDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES
from server.schemas.common import MAX_ID
from server.schemas.twin import Scenario, TwinRate, TwinState
from server.services.twin import Twin

router = APIRouter(tags=["twin"], responses=PROBLEM_RESPONSES)


def _control(twin: Twin | None, act: Callable[[Twin], object]) -> TwinState:
    """Do `act` to the twin and return its state after, refusing with 409 when it does not
    run."""
    if twin is None:
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail="the digital twin is not running; start the service with "
            "INTSPACE_SIMULATION=true",
        )
    act(twin)
    return twin.state()


@router.get("/twin", response_model=TwinState, dependencies=[ReadAccess])
def get_twin(twin: TwinDep) -> TwinState:
    """Return the twin's state: running, simulation time, the robot's pose and the people."""
    return TwinState(enabled=False) if twin is None else twin.state()


@router.post("/twin/pause", response_model=TwinState, dependencies=[WriteAccess])
def pause_twin(running: TwinDep) -> TwinState:
    """Hold the simulation."""
    return _control(running, Twin.pause)


@router.post("/twin/resume", response_model=TwinState, dependencies=[WriteAccess])
def resume_twin(running: TwinDep) -> TwinState:
    """Continue the simulation."""
    return _control(running, Twin.resume)


@router.post("/twin/reset", response_model=TwinState, dependencies=[WriteAccess])
def reset_twin(running: TwinDep) -> TwinState:
    """Put the robot at its start, the clock at zero and clear the live tracks."""
    return _control(running, Twin.reset)


@router.post("/twin/rate", response_model=TwinState, dependencies=[WriteAccess])
def set_twin_rate(body: TwinRate, running: TwinDep) -> TwinState:
    """Set the twin's frame rate (frames per second of every camera)."""
    return _control(running, lambda twin: twin.set_rate(body.rate_hz))


@router.get("/twin/scenarios", response_model=list[Scenario], dependencies=[ReadAccess])
def list_scenarios():
    """Return the twin's named scenarios (`intspace sim run NAME`; network calibration also
    as a calibration run of kind "network")."""
    return [{"name": name, "description": DESCRIPTIONS.get(name, "")} for name in SCENARIOS]


@router.get(
    "/cameras/{camera_id}/frame.jpg",
    dependencies=[ReadAccess],
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}}},
)
def camera_frame(
    camera_id: Annotated[int, Path(ge=1, le=MAX_ID)],
    twin: TwinDep,
    frames: FramesDep,
    overlay: Annotated[bool, Query(description="Draw the detections.")] = False,
) -> Response:
    """Return the camera's latest frame as JPEG: a twin camera's latest render, with the
    detections drawn (circles and labels) when `overlay`; a real camera's latest frame its
    node uploaded (PUT /cameras/{id}/frame; no overlay)."""
    frame = twin.frame(camera_id) if twin is not None else None
    if frame is None:
        uploaded = frames.get(camera_id)
        if uploaded is not None:
            return Response(
                uploaded.jpeg,
                media_type="image/jpeg",
                headers={
                    "Cache-Control": "no-store",
                    "X-Frame-Received": f"{uploaded.received:.3f}",
                },
            )
    if twin is None:
        raise HTTPException(
            status.HTTP_404_NOT_FOUND,
            detail=f"no frame of camera {camera_id}: its camera node has sent none "
            "(intspace node uploads one a second) and the digital twin is not running",
        )
    if frame is None:
        reason = (
            "it has not rendered a frame yet"
            if camera_id in twin.camera_ids.values()
            else "it is not a camera of the twin and its camera node has sent no frame"
        )
        raise HTTPException(
            status.HTTP_404_NOT_FOUND, detail=f"no frame of camera {camera_id}: {reason}"
        )
    image = frame.image
    if overlay:
        image = image.copy()
        for det in frame.detections:
            u, v = (round(c) for c in det["pixel"])
            colour = (0, 255, 255) if det["kind"] == "robot" else (255, 0, 255)
            if "bbox" in det:
                x, y, w, h = det["bbox"]
                cv2.rectangle(image, (x, y), (x + w, y + h), colour, 1)
            cv2.circle(image, (u, v), 8, colour, 2, cv2.LINE_AA)
            cv2.putText(
                image, det["kind"], (u + 10, v - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1
            )
    _, jpg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
    return Response(jpg.tobytes(), media_type="image/jpeg", headers={"Cache-Control": "no-store"})
