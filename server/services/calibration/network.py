"""Network runs (kind "network", source "twin"): the digital twin's calibration drive, the
robot's marker driven over the floor, calibrates every camera of the twin, intrinsics and pose,
registered to the world by the robot's tour of the signposts; the result carries each camera's
errors against the twin and their Cramer-Rao bound. Applying one sets every calibrated camera
that still exists, with an entry in its calibration history."""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from core.calibration.network import CalibratedCamera
from core.errors import InvalidInput
from core.sim import Scene, SensorNoise
from core.sim.network_drive import drive_marker_calibration
from core.sim.network_registration import can_register, register_network
from core.sim.render import renderer_for
from core.sim.scenarios.network import (
    DRIVE_S,
    INTRINSICS_FROM_BOARD,
    accuracy_study,
    camera_errors,
    drive_programme,
)
from core.sim.scenarios.records import AccuracyRow, CameraCalibrationError
from server.db.models import CalibrationRun, Camera
from server.schemas.calibration import (
    AccuracyCamera,
    AccuracyRowRead,
    NetworkCameraBound,
    NetworkCameraErrors,
    NetworkCameraResult,
    NetworkRegistration,
    NetworkRunResult,
)
from server.schemas.twin import NetworkRunCreate
from server.services.calibration._shared import (
    Progress,
    RunContext,
    RunRefused,
    camera_history_entry,
    no_progress,
    set_camera_calibration,
)
from server.services.scene_sync import SceneSync

KIND = "network"
Result = NetworkRunResult

# The accuracy study of a network run: drive lengths (s) and pixel noise levels (px).
STUDY_BUDGETS_S = (100.0, 200.0, 300.0)
STUDY_SIGMAS_PX = (0.25, 0.5, 1.0)
# Share of a network run's time spent in the drive and joint calibration when the study runs
# too (measured on the default home: 110 s of 250 s); the study's drives take the rest, each in
# proportion to its length.
DRIVE_SHARE = 0.45


def create(body: NetworkRunCreate, context: RunContext) -> CalibrationRun:
    """Return the (unsaved) queued network run of the twin's cameras, each named by its
    registry id. Raises RunRefused (409) without the twin."""
    twin = context.twin
    if twin is None:
        raise RunRefused(
            409,
            "a network run drives the digital twin's robot; start the service with "
            "INTSPACE_SIMULATION=true",
        )
    return CalibrationRun(
        kind=KIND,
        source="twin",
        camera_id=None,
        inputs={"space_id": twin.space_id, "cameras": dict(twin.camera_ids)},
        options=body.options.model_dump(),
    )


def compute(session: Session, run: CalibrationRun, progress: Progress) -> NetworkRunResult:
    """Return the result of a claimed network run (calibrate_network)."""
    del session  # the run's inputs name everything it needs
    return calibrate_network(run.inputs, run.options, progress)


def calibrate_network(
    inputs: dict[str, Any], options: dict[str, Any], progress: Progress = no_progress
) -> NetworkRunResult:
    """Return the result of calibrating the twin's cameras by driving the robot's
    marker (`network_calibration_drive`), each camera named by its registry id too."""
    from core.sim import default_scene

    result = network_calibration_drive(
        default_scene(),
        int(options.get("seed", 0)),
        stops=int(options.get("stops", 32)),
        minutes=float(options.get("minutes", DRIVE_S / 60.0)),
        study=bool(options.get("study", True)),
        progress=progress,
    )
    ids = inputs.get("cameras", {})
    cameras = [c.model_copy(update={"camera_id": ids.get(c.name)}) for c in result.cameras]
    return result.model_copy(update={"cameras": cameras})


def _std_of(cal: CalibratedCamera) -> dict[str, Any]:
    """Return a calibrated camera's standard deviations by parameter, with the focal length's
    (fx + fy) / 2 from the covariance."""
    names = list(cal.parameter_names)
    std = dict(zip(names, (float(v) for v in cal.std), strict=True))
    a = np.zeros(len(names))
    for n in ("fx", "fy"):
        if n in names:
            a[names.index(n)] = 0.5
    f_std = float(np.sqrt(max(float(a @ cal.covariance @ a), 0.0))) if cal.covariance.size else 0.0
    return {
        "f_px": f_std,
        "rvec_rad": [std.get(n, 0.0) for n in ("rx", "ry", "rz")],
        "t_m": [std.get(n, 0.0) for n in ("tx", "ty", "tz")],
        "parameters": std,
    }


def _camera_errors(e: CameraCalibrationError) -> NetworkCameraErrors:
    return NetworkCameraErrors(
        focal_pct=e.focal_error_pct,
        position_m=e.position_error_m,
        rotation_deg=e.rotation_error_deg,
        aligned_position_m=e.aligned_position_error_m,
        aligned_rotation_deg=e.aligned_rotation_error_deg,
        start_frame_position_m=e.start_frame_position_error_m,
        start_frame_rotation_deg=e.start_frame_rotation_error_deg,
    )


def _camera_bound(e: CameraCalibrationError) -> NetworkCameraBound:
    return NetworkCameraBound(
        focal_pct=e.bound_focal_pct,
        position_m=e.bound_position_m,
        rotation_deg=e.bound_rotation_deg,
        aligned_position_m=e.bound_aligned_position_m,
        aligned_rotation_deg=e.bound_aligned_rotation_deg,
    )


def network_calibration_drive(
    scene: Scene,
    seed: int,
    *,
    stops: int = 32,
    minutes: float = DRIVE_S / 60.0,
    study: bool = True,
    progress: Progress = no_progress,
) -> NetworkRunResult:
    """Return the result of calibrating the scene's cameras by the robot's marker
    (core.sim.network_drive: each camera's own chessboard calibration, the robot driving for
    at most `minutes` through `stops` planned stops per 5 minutes (drive_programme), the
    marker detected in rendered images, the joint calibration with the
    odometry as prior), registered to the world by the robot's tour of the signposts where the
    home has them (core.sim.network_registration; `registration`, and each camera's errors in
    the start pose's frame beside its registered ones), with each calibrated camera's K, dist,
    T_world_camera, standard deviations, per-pose residuals, its errors against the twin and
    their Cramer-Rao bound;
    with `study`, the errors and bounds as functions of drive length and pixel noise for this
    seed (core.sim.scenarios.network.accuracy_study over STUDY_BUDGETS_S x STUDY_SIGMAS_PX,
    one drive and noise level at a time so that `progress` hears of each)."""
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("the twin's robot carries no marker to calibrate the network with")
    # Shared with the running twin: the static layer of each camera is built once.
    renderer = renderer_for(scene)
    progress("driving the robot and calibrating", 0.0)
    budget, stops, revisit_below = drive_programme(minutes, stops)
    md = drive_marker_calibration(
        scene,
        seed,
        stops=stops,
        revisit_below=revisit_below,
        noise=SensorNoise(),
        renderer=renderer,
        max_drive_s=budget,
    )
    net = md.calibration
    start_frame = None
    registration: NetworkRegistration | None = None
    if can_register(scene):
        progress("touring the signposts", 0.8 * DRIVE_SHARE)
        registered_net, tour = register_network(net, scene, seed, renderer=renderer)
        reg = tour.registration
        if reg is None:
            registration = NetworkRegistration(signposts_read=tour.read, reason=tour.reason)
        else:
            start_frame, net = net, registered_net
            registration = NetworkRegistration(
                signposts_read=tour.read,
                reason=tour.reason,
                theta_deg=float(np.degrees(reg.theta)),
                theta_std_deg=reg.theta_std_deg,
                t_m=[float(v) for v in reg.t],
                sightings=len(tour.sightings),
            )
    scored = {e.name: e for e in camera_errors(net, md.true_cameras, md.bound, start_frame)}
    true = {cm.name: cm for cm in md.true_cameras}
    cameras = []
    for cal in net.cameras:
        e = scored[cal.name]
        cameras.append(
            NetworkCameraResult(
                name=cal.name,
                K=cal.K.tolist(),
                dist=cal.dist.tolist(),
                T_world_camera=cal.T_world_camera.tolist(),
                std=_std_of(cal),
                rms=cal.rms,
                poses_seen=cal.poses_seen,
                detections=cal.detections,
                outliers=cal.outliers,
                pose_residuals=[
                    [int(j), float(r[0]), float(r[1])]
                    for j, r in zip(cal.pose_index, cal.residuals, strict=True)
                ],
                errors=_camera_errors(e),
                bound=_camera_bound(e),
                image_size=[true[cal.name].width, true[cal.name].height],
            )
        )
    accuracy: list[AccuracyRowRead] = []
    if study:
        # Each (drive length, noise) row of the study draws from its own generator, seeded by
        # (seed, length): one call per row gives the rows of one call over all of them.
        cases = [(b, s) for b in STUDY_BUDGETS_S for s in STUDY_SIGMAS_PX]
        done_at = np.cumsum([0.0] + [b for b, _ in cases]) / sum(b for b, _ in cases)
        rows: list[AccuracyRow] = []
        for k, (budget, sigma) in enumerate(cases):
            progress("accuracy study", DRIVE_SHARE + (1 - DRIVE_SHARE) * float(done_at[k]))
            rows += accuracy_study(
                scene,
                (seed,),
                budgets=(budget,),
                sigmas=(sigma,),
                session=md.intrinsics,
                renderer=renderer,
            )
        for row in rows:
            accuracy.append(
                AccuracyRowRead(
                    stops=row.stops,
                    poses=row.poses,
                    drive_s=row.drive_s,
                    sigma_px=row.sigma_px,
                    cameras=[
                        AccuracyCamera(
                            name=c.name, errors=_camera_errors(c), bound=_camera_bound(c)
                        )
                        for c in row.cameras
                    ],
                    rejected=list(row.rejected),
                )
            )
    pose_rms = net.pose_rms_px
    return NetworkRunResult(
        kind="network",
        target="marker",
        poses=md.poses,
        detections=int(md.seen.sum()),
        drive_s=md.drive.duration_s,
        sigma_px=md.observations.sigma_px,
        intrinsics_from=INTRINSICS_FROM_BOARD,
        rms_px=net.rms_px,
        rms_whitened=net.rms_whitened,
        residual_variance=net.residual_variance,
        pose_rms_px=[None if not np.isfinite(v) else float(v) for v in pose_rms],
        cameras=cameras,
        rejected=[
            {"name": r.name, "reason": r.reason, "poses_seen": r.poses_seen} for r in net.rejected
        ],
        accuracy=accuracy,
        registration=registration,
    )


def apply(session: Session, run: CalibrationRun, scene: SceneSync) -> list[Camera]:
    """Set intrinsics and pose of every camera the run calibrated that still exists, each with
    an entry in its calibration history (once: a camera that has the run already is left as
    it is); return those cameras. Raises RunRefused (409) when they were all deleted."""
    # Only the fields applying reads: a result is what its run stored, whatever version wrote it.
    cameras, changed = [], []
    for calibrated in run.result["cameras"] if run.result else []:
        camera = session.get(Camera, calibrated.get("camera_id") or 0)
        if camera is None:
            continue  # deleted since the run
        cameras.append(camera)
        values = {k: calibrated[k] for k in ("K", "dist", "T_world_camera")}
        if not set_camera_calibration(session, camera.id, run.id, values):
            continue  # applied already
        changed.append(camera)
        session.add(
            camera_history_entry(
                camera.id,
                run.id,
                calibrated["K"],
                calibrated["dist"],
                calibrated["rms"],
                calibrated["image_size"],
            )
        )
    if not cameras:
        raise RunRefused(409, f"the cameras of run {run.id} were all deleted")
    session.commit()
    for camera in cameras:
        session.refresh(camera)
    for camera in changed:
        scene.camera_changed(camera)
    return cameras
