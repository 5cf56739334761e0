"""Intrinsics runs (kind "intrinsics"): Zhang's calibration of one camera, from inline point
correspondences (source "correspondences") or from uploaded photos of a chessboard (source
"images", the photos stored with the run). Applying one sets the camera's K and distortion and
adds an entry to its calibration history."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from core.calibration.detect import find_chessboard
from core.calibration.zhang import CameraCalibration, calibrate_camera
from core.errors import PatternNotFound
from server.db.models import CalibrationRun, CalibrationRunFile, Camera
from server.schemas.calibration import CalibrationResult, IntrinsicsRunCreate, SkippedPhoto
from server.services.calibration._shared import (
    Progress,
    RunContext,
    RunRefused,
    camera_history_entry,
    existing,
    no_progress,
    run_camera,
    set_camera_calibration,
)
from server.services.calibration.io import board_object_points_for, decode_image
from server.services.scene_sync import SceneSync

KIND = "intrinsics"
Result = CalibrationResult


def check_image_size(
    session: Session, camera_id: int, size: tuple[int, ...], field: str, location: str
) -> None:
    """Refuse (409) a run whose images are not the size of its camera's: its result could
    never be applied to that camera."""
    camera = session.get(Camera, camera_id)
    if camera is not None and (camera.width, camera.height) != size:
        raise RunRefused(
            409,
            f"the images are {size[0]}x{size[1]} but camera {camera_id} is "
            f"{camera.width}x{camera.height}; calibrate with images of the camera's size or "
            "fix the camera's width and height first",
            field,
            location,
        )


def create(body: IntrinsicsRunCreate, context: RunContext) -> CalibrationRun:
    """Return the (unsaved) queued run of inline correspondences of one camera. Raises
    RunRefused: an unknown camera (422), images not of the camera's size (409)."""
    existing(context.session, Camera, body.camera_id, "camera_id")
    check_image_size(context.session, body.camera_id, tuple(body.image_size), "image_size", "body")
    return CalibrationRun(
        kind=KIND,
        source="correspondences",
        camera_id=body.camera_id,
        inputs=body.model_dump(include={"image_size", "object_points", "image_points"}),
        options=body.options.model_dump(),
    )


def create_from_images(
    session: Session,
    camera_id: int,
    photos: list[CalibrationRunFile],
    image_size: tuple[int, int],
    chessboard: tuple[int, int],
    square_m: float,
    options: dict[str, Any],
) -> CalibrationRun:
    """Return the (unsaved) queued run of photos of a chessboard (`chessboard` its inner
    corners, columns x rows; `square_m` its square's side) taken by camera `camera_id`, every
    photo `image_size` (width, height). Raises RunRefused (409) when that is not the camera's
    size."""
    check_image_size(session, camera_id, image_size, "files", "form")
    return CalibrationRun(
        kind=KIND,
        source="images",
        camera_id=camera_id,
        inputs={
            "chessboard": list(chessboard),
            "square_m": square_m,
            "image_size": list(image_size),
        },
        options=options,
        files=photos,
    )


def _result(
    calibration: CameraCalibration,
    views_used: list[int] | None,
    skipped: list[SkippedPhoto] | None = None,
) -> CalibrationResult:
    # A run from correspondences has no photos to skip: its stored result has no `skipped`.
    extra = {} if skipped is None else {"skipped": skipped}
    return CalibrationResult(
        K=np.asarray(calibration.K, dtype=float).tolist(),
        dist=np.asarray(calibration.dist, dtype=float).ravel().tolist(),
        rms=float(calibration.rms),
        std_intrinsics={k: float(v) for k, v in calibration.std_intrinsics.items()},
        per_view_rms=np.asarray(calibration.per_view_rms, dtype=float).ravel().tolist(),
        image_size=[int(v) for v in calibration.image_size],
        views_used=views_used,
        **extra,
    )


def calibrate_from_correspondences(
    inputs: dict[str, Any], options: dict[str, Any], progress: Progress = no_progress
) -> CalibrationResult:
    """Return the result of Zhang's calibration on inline correspondences."""
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
    progress: Progress = no_progress,
    *,
    names: Sequence[str] | None = None,
) -> CalibrationResult:
    """Return the result of Zhang's calibration on photos of a chessboard. Photos that
    cannot be used are skipped and named in `skipped` with the reason (their indices are
    missing from views_used); raises PatternNotFound, naming them, when none can be used."""
    names = list(names) if names is not None else [f"image-{i}" for i in range(len(images))]
    cols, rows = inputs["chessboard"]
    model = board_object_points_for(cols, rows, float(inputs["square_m"]))
    object_points, image_points, used = [], [], []
    skipped: list[SkippedPhoto] = []
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
        listed = "; ".join(f"{s.filename}: {s.reason}" for s in skipped[:10])
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
    return _result(calibration, used, skipped)


def _skip(index: int, names: Sequence[str], reason: str) -> SkippedPhoto:
    return SkippedPhoto(index=index, filename=names[index], reason=reason)


def compute(session: Session, run: CalibrationRun, progress: Progress) -> CalibrationResult:
    """Return the result of a claimed intrinsics run: from its photos (source "images",
    read from the database in upload order) or its correspondences."""
    if run.source != "images":
        return calibrate_from_correspondences(run.inputs, run.options, progress)
    files = session.execute(
        select(CalibrationRunFile.filename, CalibrationRunFile.data)
        .where(CalibrationRunFile.run_id == run.id)
        .order_by(CalibrationRunFile.position)
    ).all()
    return calibrate_from_images(
        [f.data for f in files],
        run.inputs,
        run.options,
        progress,
        names=[f.filename for f in files],
    )


def apply(session: Session, run: CalibrationRun, scene: SceneSync) -> Camera:
    """Set the camera's K and distortion from a succeeded run and record it in the camera's
    calibration history; return the camera. Applying the run the camera already has changes
    nothing and adds no history entry. Raises RunRefused (409) when the camera was deleted or
    resized since."""
    camera = run_camera(
        session,
        run,
        "calibrated {width}x{height} images",
        "fix the camera's size or calibrate again",
    )
    # Only the fields applying reads: a result is what its run stored, whatever version wrote it.
    result = run.result
    assert result is not None
    if set_camera_calibration(
        session, camera.id, run.id, {"K": result["K"], "dist": result["dist"]}
    ):
        session.add(
            camera_history_entry(
                camera.id,
                run.id,
                result["K"],
                result["dist"],
                result.get("rms"),
                result["image_size"],
            )
        )
        session.commit()
        session.refresh(camera)
        scene.camera_changed(camera)
    return camera
