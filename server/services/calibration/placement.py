"""Placement runs (kind "placement"): a camera placed from floor points, created finished by
POST /cameras/{id}/placement (the fit takes milliseconds), stored like any calibration run and
applied through the same route.

A run of kind "placement" (source "points") keeps the clicked pairs as its inputs and the
camera's intrinsics it was computed with; its result is the camera's pose T_world_camera, K
(estimated when the camera had none), every point's residual and the standard deviations.
Applying it sets the camera's pose, and its K and distortion when they were estimated.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from core.calibration import place_camera
from server.db.base import utcnow
from server.db.models import RUN_SUCCEEDED, CalibrationRun, Camera
from server.schemas.calibration import PlacementCreate, PlacementRunResult, PlacementStd
from server.schemas.common import stored_json
from server.services.calibration._shared import (
    Progress,
    camera_history_entry,
    run_camera,
    set_camera_calibration,
)
from server.services.scene_sync import SceneSync

KIND = "placement"
Result = PlacementRunResult


def placement_inputs(body: PlacementCreate, camera: Camera) -> dict[str, Any]:
    """Return the stored inputs of a placement of `camera`: its points, image size and the
    intrinsics it has now (None: the focal length is estimated)."""
    return {
        "points": [p.model_dump() for p in body.points],
        "image_size": [camera.width, camera.height],
        "K": camera.K,
        "dist": camera.dist,
    }


def compute_placement(camera_id: int, inputs: dict[str, Any]) -> PlacementRunResult:
    """Return the result of a placement run's stored inputs (placement_inputs'; raising
    core's typed errors)."""
    points = inputs["points"]
    world = np.array([[*p["floor"], p.get("z", 0.0)] for p in points], dtype=np.float64)
    pixels = np.array([p["pixel"] for p in points], dtype=np.float64).reshape(-1, 2)
    K = inputs.get("K")
    fit = place_camera(
        world.reshape(-1, 3),
        pixels,
        tuple(inputs["image_size"]),
        None if K is None else np.asarray(K),
        None if K is None else inputs.get("dist"),
    )
    return PlacementRunResult(
        kind="placement",
        camera_id=camera_id,
        T_world_camera=fit.T_world_camera.tolist(),
        K=fit.K.tolist(),
        dist=fit.dist.tolist(),
        f_estimated=fit.f_estimated,
        residuals_px=fit.residuals_px.tolist(),
        residuals=fit.residuals.tolist(),
        rejected=fit.rejected.tolist(),
        rms=fit.rms,
        std=PlacementStd(
            position_m=fit.std_position_m.tolist(),
            rotation_deg=fit.std_rotation_deg.tolist(),
            f_px=fit.std_f_px,
        ),
        image_size=list(inputs["image_size"]),
    )


def create(body: PlacementCreate, camera: Camera) -> CalibrationRun:
    """Return a finished placement run of `camera` (not yet added to a session)."""
    inputs = placement_inputs(body, camera)
    result = compute_placement(camera.id, inputs)
    now = utcnow()
    return CalibrationRun(
        kind=KIND,
        source="points",
        status=RUN_SUCCEEDED,
        camera_id=camera.id,
        inputs=inputs,
        options={},
        result=stored_json(result),
        attempts=0,
        started_at=now,
        finished_at=now,
    )


def compute(session: Session, run: CalibrationRun, progress: Progress) -> PlacementRunResult:
    """Return the result of a placement run's inputs again (it was made finished; it is
    computed here only if it was re-queued)."""
    del session, progress
    return compute_placement(run.camera_id or 0, run.inputs)


def placement_values(result: dict[str, Any]) -> dict[str, Any]:
    """Return the camera columns a stored placement result sets (column name to value): the
    pose, and K and distortion when they were estimated (a camera with known intrinsics keeps
    them). Only the fields applying reads: a result is what its run stored, whatever version
    wrote it."""
    values: dict[str, Any] = {"T_world_camera": result["T_world_camera"]}
    if result.get("f_estimated"):
        values["K"] = result["K"]
        values["dist"] = result["dist"]
    return values


def apply(session: Session, run: CalibrationRun, scene: SceneSync) -> Camera:
    """Set a camera's pose (and K and distortion when the run estimated them) from a
    placement run, recording it in the camera's calibration history; return the camera.
    Applying the run the camera already has changes nothing. Raises RunRefused (409) when the
    camera was deleted or resized since."""
    camera = run_camera(session, run, "placed a {width}x{height} camera", "place it again")
    assert run.result is not None
    values = placement_values(run.result)
    if set_camera_calibration(session, camera.id, run.id, values):
        session.add(
            camera_history_entry(
                camera.id,
                run.id,
                values.get("K", camera.K),
                values.get("dist", camera.dist or [0.0] * 5),
                run.result.get("rms"),
                run.result["image_size"],
            )
        )
        session.commit()
        session.refresh(camera)
        scene.camera_changed(camera)
    return camera
