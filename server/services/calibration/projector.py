"""Projector runs (kind "projector", source "twin"): the twin's `projector-calibration`
scenario, the twin's projector drawing spots on the floor that the registry's calibrated
ceiling cameras locate, fits the projector's mount and tilt offset. Applying one sets the
projector's pose and adds an entry to its calibration history."""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from server.db.models import CalibrationRun, Camera, Projector, ProjectorCalibration
from server.schemas.calibration import ProjectorRunResult, ProjectorTwinErrors
from server.schemas.paths import ProjectorRunCreate
from server.services.calibration._shared import Progress, RunContext, RunRefused
from server.services.cameras import network_camera
from server.services.floor_plan import twin_scene_of
from server.services.scene_sync import SceneSync

KIND = "projector"
Result = ProjectorRunResult


def create(body: ProjectorRunCreate, context: RunContext) -> CalibrationRun:
    """Return the (unsaved) queued projector calibration run of a registered projector on the
    twin, with the calibrated cameras that will locate its spots. Raises RunRefused naming the
    field: an unknown projector (422), the projector not in the twin's home (409), fewer than
    two usable cameras of the twin's (422)."""
    session = context.session
    projector = session.get(Projector, body.projector_id)
    if projector is None:
        raise RunRefused(422, f"no projector with id {body.projector_id}", "projector_id")
    scene = (
        None
        if projector.space_id is None
        else twin_scene_of(context.twin, session, projector.space_id)
    )
    seed = body.seed if body.seed is not None else context.twin_seed
    camera_ids = body.camera_ids
    if scene is None or scene.projector is None:
        raise RunRefused(
            409,
            f"projector {projector.id} is not in the digital twin's home: a projector "
            "calibration run commands the twin's projector",
            "projector_id",
        )
    if camera_ids is None:
        rows = session.scalars(
            select(Camera).where(Camera.space_id == projector.space_id).order_by(Camera.id)
        ).all()
    else:
        found = {c.id: c for c in session.scalars(select(Camera).where(Camera.id.in_(camera_ids)))}
        missing = [i for i in camera_ids if i not in found]
        if missing:
            raise RunRefused(422, f"no camera with id {missing[0]}", "camera_ids")
        rows = [found[i] for i in camera_ids]
    twin_names = {c.name for c in scene.cameras}
    cameras, refused = [], []
    for c in rows:
        if c.name not in twin_names:
            refused.append(f"camera {c.id} ({c.name}) is not one of the twin's")
        elif c.K is None or c.T_world_camera is None:
            refused.append(f"camera {c.id} ({c.name}) has no intrinsics or pose")
        else:
            cameras.append(
                {
                    "camera_id": c.id,
                    "name": c.name,
                    "K": c.K,
                    "dist": c.dist,
                    "T_world_camera": c.T_world_camera,
                    "width": c.width,
                    "height": c.height,
                }
            )
    if len(cameras) < 2:
        raise RunRefused(
            422,
            f"locating the spots takes at least two calibrated cameras of the twin; "
            f"{len(cameras)} usable" + "".join(f"; {why}" for why in refused),
            "camera_ids",
        )
    return CalibrationRun(
        kind=KIND,
        source="twin",
        camera_id=None,
        inputs={"projector_id": projector.id, "cameras": cameras},
        options={"seed": seed, "images": body.images},
    )


def compute(session: Session, run: CalibrationRun, progress: Progress) -> ProjectorRunResult:
    """Return the result of a claimed projector run (calibrate_projector_run)."""
    del session  # the cameras locating the spots were stored with the run
    return calibrate_projector_run(run.inputs, run.options, progress)


def calibrate_projector_run(
    inputs: dict[str, Any], options: dict[str, Any], progress: Progress
) -> ProjectorRunResult:
    """Return the result of a projector calibration run (its inputs and options are the run's
    JSON columns): the twin's
    `projector-calibration` scenario (core.sim.scenarios.projector_calibration)
    with the registry's calibrated cameras locating the spots."""
    # Imported here: a worker loads the twin's navigation scenarios only when it needs them.
    from core.sim import default_scene
    from core.sim.scenarios.projector_calibration import projector_calibration

    scene = default_scene()
    cams = inputs["cameras"]
    progress("locating the spots", 0.1)
    cameras = [network_camera(c) for c in cams]
    fit = projector_calibration(
        scene,
        int(options.get("seed", 0)),
        cameras=cameras,
        cameras_from="the registry's calibrated cameras",
        images=bool(options.get("images", True)),
    )
    progress("done", 1.0)
    return ProjectorRunResult(
        kind="projector",
        projector_id=int(inputs["projector_id"]),
        T_world_projector=fit.model.T_world_base.tolist(),
        tilt_offset_rad=float(fit.model.theta[1]),
        spots=fit.spots,
        rms_m=fit.rms_m,
        position_std_m=fit.position_std_m,
        rotation_std_deg=fit.rotation_std_deg,
        spot_error_rms_m=fit.spot_error_rms_m,
        cameras=list(fit.cameras),
        camera_ids=[int(c["camera_id"]) for c in cams],
        spots_from=fit.spots_from,
        twin_errors=ProjectorTwinErrors(
            position_m=fit.position_error_m,
            rotation_deg=fit.rotation_error_deg,
            aligned_position_m=fit.aligned_position_error_m,
            aligned_rotation_deg=fit.aligned_rotation_error_deg,
            tilt_offset_rad=fit.tilt_offset_error_rad,
        ),
    )


def latest_calibration(session: Session, projector_id: int) -> ProjectorCalibration | None:
    """Return the newest entry of a projector's calibration history, None when it has none."""
    return session.scalars(
        select(ProjectorCalibration)
        .where(ProjectorCalibration.projector_id == projector_id)
        .order_by(ProjectorCalibration.id.desc())
        .limit(1)
    ).first()


def apply(session: Session, run: CalibrationRun, scene: SceneSync) -> Projector:
    """Set the projector's pose from a succeeded projector run and record it in the
    projector's calibration history (once: applying the run in force again adds nothing);
    return the projector, which the 3D scene then draws with its beam from the new pose.
    Raises RunRefused (409) when the projector is gone."""
    # Only the fields applying reads: a result is what its run stored, whatever version wrote it.
    assert run.result is not None
    result = run.result
    projector = session.get(Projector, int(result["projector_id"]))
    if projector is None:
        raise RunRefused(
            409,
            f"projector {result['projector_id']} of run {run.id} was deleted",
            "run_id",
            "path",
        )
    latest = latest_calibration(session, projector.id)
    if (
        latest is not None
        and latest.calibration_run_id == run.id
        and projector.T_world_projector == result["T_world_projector"]
    ):
        scene.projector_changed(projector)
        return projector
    projector.T_world_projector = result["T_world_projector"]
    session.add(
        ProjectorCalibration(
            projector_id=projector.id,
            calibration_run_id=run.id,
            T_world_projector=result["T_world_projector"],
            tilt_offset=float(result["tilt_offset_rad"]),
            rms_m=float(result["rms_m"]),
            spots=int(result["spots"]),
        )
    )
    session.commit()
    scene.projector_changed(projector)
    return projector
