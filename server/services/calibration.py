"""Calibration jobs: decode inputs, call core.calibration, shape the result for storage."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np

from core.calibration.detect import Chessboard, board_object_points, find_chessboard
from core.calibration.io import CalibrationRecord, to_opencv_yaml, to_ros_yaml
from core.calibration.network import CalibratedCamera
from core.calibration.zhang import CameraCalibration, calibrate_camera
from core.errors import InvalidInput, PatternNotFound
from core.sim import Scene, SensorNoise
from core.sim.network_drive import drive_marker_calibration
from core.sim.network_registration import can_register, register_network
from core.sim.network_scenarios import (
    DRIVE_S,
    INTRINSICS_FROM_BOARD,
    accuracy_study,
    camera_errors,
    drive_programme,
)
from core.sim.render import renderer_for
from core.sim.scenario_records import CameraCalibrationError

# Reports how far a run has come: (stage, fraction of the whole run 0-1); may raise to stop it.
Progress = Callable[[str, float], None]

# The accuracy study of a network run: drive lengths (s) and pixel noise levels (px).
STUDY_BUDGETS_S = (100.0, 200.0, 300.0)
STUDY_SIGMAS_PX = (0.25, 0.5, 1.0)
# Share of a network run's time spent in the drive and joint calibration when the study runs
# too (measured on the default home: 110 s of 250 s); the study's drives take the rest, each in
# proportion to its length.
DRIVE_SHARE = 0.45


def _no_progress(stage: str, fraction: float) -> None:
    del stage, fraction


def decode_image(data: bytes, max_pixels: int) -> np.ndarray | None:
    """Return the decoded image (grey or BGR uint8), None when `data` is not an image OpenCV
    can read or holds more than `max_pixels` pixels."""
    if not data:
        return None
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.ndim not in (2, 3) or image.shape[0] * image.shape[1] > max_pixels:
        return None
    if image.dtype != np.uint8:
        image = cv2.convertScaleAbs(image, alpha=255.0 / max(float(image.max()), 1.0))
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image


def _result(calibration: CameraCalibration, views_used: list[int] | None) -> dict[str, Any]:
    return {
        "K": np.asarray(calibration.K, dtype=float).tolist(),
        "dist": np.asarray(calibration.dist, dtype=float).ravel().tolist(),
        "rms": float(calibration.rms),
        "std_intrinsics": {k: float(v) for k, v in calibration.std_intrinsics.items()},
        "per_view_rms": np.asarray(calibration.per_view_rms, dtype=float).ravel().tolist(),
        "image_size": [int(v) for v in calibration.image_size],
        "views_used": views_used,
    }


def calibrate_from_correspondences(
    inputs: dict[str, Any], options: dict[str, Any], progress: Progress = _no_progress
) -> dict:
    """Return the stored result of Zhang's calibration on inline correspondences."""
    progress("calibrating", 0.0)
    calibration = calibrate_camera(
        [np.asarray(v, dtype=float) for v in inputs["object_points"]],
        [np.asarray(v, dtype=float) for v in inputs["image_points"]],
        tuple(inputs["image_size"]),
        skew=bool(options.get("skew", False)),
        distortion=str(options.get("distortion", "k1k2p1p2")),
    )
    return _result(calibration, None)


def calibrate_from_images(
    images: Sequence[bytes],
    inputs: dict[str, Any],
    options: dict[str, Any],
    progress: Progress = _no_progress,
    *,
    names: Sequence[str] | None = None,
) -> dict:
    """Return the stored result of Zhang's calibration on photos of a chessboard. Photos that
    cannot be used are skipped and named in `skipped` with the reason (their indices are
    missing from views_used); raises PatternNotFound, naming them, when none can be used."""
    names = list(names) if names is not None else [f"image-{i}" for i in range(len(images))]
    cols, rows = inputs["chessboard"]
    model = board_object_points_for(cols, rows, float(inputs["square_m"]))
    object_points, image_points, used = [], [], []
    skipped: list[dict[str, Any]] = []
    for index, data in enumerate(images):
        # Detection is most of the run; the calibration itself takes the last tenth.
        progress("detecting the chessboard", 0.9 * index / len(images))
        image = decode_image(data, max_pixels=2**31)
        if image is None:
            skipped.append(_skip(index, names, "not an image OpenCV can decode"))
            continue
        try:
            detection = find_chessboard(image, (cols, rows))
        except PatternNotFound:
            skipped.append(_skip(index, names, f"no {cols}x{rows} chessboard found"))
            continue
        except cv2.error:
            # OpenCV's detectors assert on images too small for their windows.
            skipped.append(_skip(index, names, "too small for the chessboard detector"))
            continue
        object_points.append(model[detection.ids])
        image_points.append(detection.corners)
        used.append(index)
    if not used:
        listed = "; ".join(f"{s['filename']}: {s['reason']}" for s in skipped[:10])
        more = f" (and {len(skipped) - 10} more)" if len(skipped) > 10 else ""
        raise PatternNotFound(
            f"no {cols}x{rows} chessboard (inner corners) found in any of the {len(images)} "
            f"images ({listed}{more}); check the pattern size (inner corners, not squares) "
            "and the photos"
        )
    progress("calibrating", 0.9)
    calibration = calibrate_camera(
        object_points,
        image_points,
        tuple(inputs["image_size"]),
        skew=bool(options.get("skew", False)),
        distortion=str(options.get("distortion", "k1k2p1p2")),
    )
    return {**_result(calibration, used), "skipped": skipped}


def _skip(index: int, names: Sequence[str], reason: str) -> dict[str, Any]:
    return {"index": index, "filename": names[index], "reason": reason}


def calibrate_network(
    inputs: dict[str, Any], options: dict[str, Any], progress: Progress = _no_progress
) -> dict:
    """Return the stored result of calibrating the twin's cameras by driving the robot's
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
    for camera in result["cameras"]:
        camera["camera_id"] = ids.get(camera["name"])
    return result


def board_object_points_for(cols: int, rows: int, square_m: float) -> np.ndarray:
    """Return the (cols * rows, 3) model points of a chessboard of inner corners, metres."""
    return board_object_points(Chessboard(cols, rows), square_m)


def calibration_yaml(
    K: list[list[float]],
    dist: list[float],
    image_size: tuple[int, int],
    fmt: str,
    *,
    camera_name: str,
    rms: float | None = None,
) -> str:
    """Return a calibration as OpenCV FileStorage YAML ("opencv") or ROS camera_info YAML
    ("ros"), written by core.calibration.io."""
    record = CalibrationRecord(
        K=np.asarray(K, dtype=float),
        dist=np.asarray(dist, dtype=float),
        image_size=image_size,
        rms=rms,
        camera_name=camera_name,
    )
    return to_ros_yaml(record) if fmt == "ros" else to_opencv_yaml(record)


def _std_of(cal: CalibratedCamera) -> dict[str, Any]:
    """Return a calibrated camera's standard deviations by parameter, with the focal length's
    (fx + fy) / 2 from the covariance."""
    names = list(cal.parameter_names)
    std = dict(zip(names, (float(v) for v in cal.std), strict=True))
    a = np.zeros(len(names))
    for n in ("fx", "fy"):
        if n in names:
            a[names.index(n)] = 0.5
    f_std = float(np.sqrt(max(a @ cal.covariance @ a, 0.0))) if cal.covariance.size else 0.0
    return {
        "f_px": f_std,
        "rvec_rad": [std.get(n, 0.0) for n in ("rx", "ry", "rz")],
        "t_m": [std.get(n, 0.0) for n in ("tx", "ty", "tz")],
        "parameters": std,
    }


def _camera_errors(e: CameraCalibrationError) -> dict[str, Any]:
    return {
        "focal_pct": e.focal_error_pct,
        "position_m": e.position_error_m,
        "rotation_deg": e.rotation_error_deg,
        "aligned_position_m": e.aligned_position_error_m,
        "aligned_rotation_deg": e.aligned_rotation_error_deg,
        "start_frame_position_m": e.start_frame_position_error_m,
        "start_frame_rotation_deg": e.start_frame_rotation_error_deg,
    }


def _camera_bound(e: CameraCalibrationError) -> dict[str, Any]:
    return {
        "focal_pct": e.bound_focal_pct,
        "position_m": e.bound_position_m,
        "rotation_deg": e.bound_rotation_deg,
        "aligned_position_m": e.bound_aligned_position_m,
        "aligned_rotation_deg": e.bound_aligned_rotation_deg,
    }


def network_calibration_drive(
    scene: Scene,
    seed: int,
    *,
    stops: int = 32,
    minutes: float = DRIVE_S / 60.0,
    study: bool = True,
    progress: Progress = _no_progress,
) -> dict[str, Any]:
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
    seed (core.sim.network_scenarios.accuracy_study over STUDY_BUDGETS_S x STUDY_SIGMAS_PX,
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
    registration: dict[str, Any] | None = None
    if can_register(scene):
        progress("touring the signposts", 0.8 * DRIVE_SHARE)
        registered_net, tour = register_network(net, scene, seed, renderer=renderer)
        reg = tour.registration
        registration = {"signposts_read": tour.read, "reason": tour.reason}
        if reg is not None:
            start_frame, net = net, registered_net
            registration.update(
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
            {
                "name": cal.name,
                "K": cal.K.tolist(),
                "dist": cal.dist.tolist(),
                "T_world_camera": cal.T_world_camera.tolist(),
                "std": _std_of(cal),
                "rms": cal.rms,
                "poses_seen": cal.poses_seen,
                "detections": cal.detections,
                "outliers": cal.outliers,
                "pose_residuals": [
                    [int(j), float(r[0]), float(r[1])]
                    for j, r in zip(cal.pose_index, cal.residuals, strict=True)
                ],
                "errors": _camera_errors(e),
                "bound": _camera_bound(e),
                "image_size": [true[cal.name].width, true[cal.name].height],
            }
        )
    accuracy = []
    if study:
        # Each (drive length, noise) row of the study draws from its own generator, seeded by
        # (seed, length): one call per row gives the rows of one call over all of them.
        cases = [(b, s) for b in STUDY_BUDGETS_S for s in STUDY_SIGMAS_PX]
        done_at = np.cumsum([0.0] + [b for b, _ in cases]) / sum(b for b, _ in cases)
        rows = []
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
                {
                    "stops": row.stops,
                    "poses": row.poses,
                    "drive_s": row.drive_s,
                    "sigma_px": row.sigma_px,
                    "cameras": [
                        {"name": c.name, "errors": _camera_errors(c), "bound": _camera_bound(c)}
                        for c in row.cameras
                    ],
                    "rejected": list(row.rejected),
                }
            )
    pose_rms = net.pose_rms_px
    return {
        "kind": "network",
        "target": "marker",
        "poses": md.poses,
        "detections": int(md.seen.sum()),
        "drive_s": md.drive.duration_s,
        "sigma_px": md.observations.sigma_px,
        "intrinsics_from": INTRINSICS_FROM_BOARD,
        "rms_px": net.rms_px,
        "rms_whitened": net.rms_whitened,
        "residual_variance": net.residual_variance,
        "pose_rms_px": [None if not np.isfinite(v) else float(v) for v in pose_rms],
        "cameras": cameras,
        "rejected": [
            {"name": r.name, "reason": r.reason, "poses_seen": r.poses_seen} for r in net.rejected
        ],
        "accuracy": accuracy,
        "registration": registration,
    }
