"""Hand-eye runs (kind "hand-eye"): an arm's eye-in-hand camera, X = T_ee_camera, calibrated
on the twin (source "twin": views simulated with the twin's arm and camera, every method scored
against the twin's truth) or from uploaded pose pairs (source "poses", optionally refined by
reprojection). Applying one sets the arm's T_ee_camera and adds an entry to its hand-eye
history.

The twin's simulated eye-in-hand camera sits where core.manipulation's default manipulator
mounts it; that true mount only renders what the camera sees and scores the results, as in
core.sim.scenarios.manipulation: no estimate reads it.
"""

from __future__ import annotations

import secrets
from collections.abc import Sequence
from typing import Any

import numpy as np
from sqlalchemy import or_, update
from sqlalchemy.orm import Session

from core.manipulation import METHODS, DegenerateMotions, calibrate_hand_eye
from core.manipulation.hand_eye import check_motions, relative_motions
from core.sim.eye_in_hand import hand_eye_error, hand_eye_views
from server.db.base import utcnow
from server.db.models import Arm, CalibrationRun, Camera, HandEyeCalibration
from server.schemas.calibration import HandEyeMethodRow, HandEyeRunResult
from server.schemas.manipulation import ArmRead, HandEyeRunCreate
from server.services.calibration._shared import (
    Progress,
    RunContext,
    RunRefused,
    existing,
    found,
)
from server.services.jobs import rows_changed
from server.services.manipulation import (
    ArmKinematics,
    Problem,
    arm_read,
    closed_form,
    twin_manipulator,
)
from server.services.scene_sync import SceneSync

KIND = "hand-eye"
Result = HandEyeRunResult


def create(body: HandEyeRunCreate, context: RunContext) -> CalibrationRun:
    """Return the (unsaved) queued run of a hand-eye request, refusing (RunRefused) what it
    could not calibrate: 409 without the twin for source "twin"; 422 naming the field for an
    unknown arm, an arm the twin cannot simulate, pose pairs whose motions are degenerate or
    whose pixels do not match, refinement without K."""
    session = context.session
    arm = existing(session, Arm, body.arm_id, "arm_id")
    values = ArmKinematics.of(arm)
    options: dict[str, Any] = {"method": body.method, "refine": body.refine}
    inputs: dict[str, Any] = {"arm_id": arm.id, "arm": values.as_json(), "source": body.source}
    if body.source == "twin":
        if context.twin is None:
            raise RunRefused(
                409,
                "a twin hand-eye run simulates the twin's arm and camera; start the "
                "service with INTSPACE_SIMULATION=true, or upload your arm's pose pairs "
                "(source 'poses')",
            )
        if not closed_form(values):
            raise RunRefused(
                422,
                f"arm {arm.id} is not of the Puma type whose closed-form inverse kinematics "
                "places the twin's views; calibrate it from pose pairs (source 'poses')",
                "arm_id",
            )
        twin = body.twin.model_dump()
        if twin["seed"] is None:
            twin["seed"] = secrets.randbelow(2**31)
        options.update(twin)
    else:
        assert body.T_base_ee is not None and body.T_cam_target is not None
        problem = pose_pairs_problem(
            body.T_base_ee, body.T_cam_target, body.image_points, body.object_points
        )
        if problem is not None:
            field, reason = problem
            raise RunRefused(422, reason, field)
        K, dist = body.K, body.dist
        if body.image_points is not None and K is None:
            camera = session.get(Camera, arm.camera_id) if arm.camera_id is not None else None
            if camera is None or camera.K is None:
                raise RunRefused(
                    422,
                    "refining by reprojection needs the camera's K: give K (and dist), or "
                    "give the arm a calibrated eye-in-hand camera",
                    "K",
                )
            K, dist = camera.K, dist if dist is not None else camera.dist
        inputs.update(
            T_base_ee=body.T_base_ee,
            T_cam_target=body.T_cam_target,
            object_points=body.object_points,
            image_points=body.image_points,
            K=K,
            dist=dist,
        )
    return CalibrationRun(
        kind=KIND,
        source=body.source,
        camera_id=arm.camera_id,
        arm_id=arm.id,
        inputs=inputs,
        options=options,
    )


def pose_pairs_problem(
    T_base_ee: Sequence[Any],
    T_cam_target: Sequence[Any],
    image_points: Sequence[Any] | None,
    object_points: Sequence[Any] | None,
) -> Problem | None:
    """Return (field, reason) when uploaded pose pairs cannot be calibrated (unequal counts,
    a degenerate motion set, pixels that do not match the views), None when they can."""
    n = len(T_base_ee)
    if len(T_cam_target) != n:
        return (
            "T_cam_target",
            f"{len(T_cam_target)} target poses for {n} end-effector poses; give one of each "
            "per view",
        )
    try:
        A, _ = relative_motions(
            np.asarray(T_base_ee, dtype=float), np.asarray(T_cam_target, dtype=float)
        )
        check_motions(A)
    except DegenerateMotions as exc:
        return ("T_base_ee", f"degenerate motions: {exc}")
    if (image_points is None) != (object_points is None):
        return (
            "image_points" if image_points is None else "object_points",
            "refinement needs both object_points and image_points (and K); give both or none",
        )
    if image_points is not None and object_points is not None:
        if len(image_points) != n:
            return ("image_points", f"{len(image_points)} views of pixels for {n} pose pairs")
        m = len(object_points)
        for i, view in enumerate(image_points):
            if len(view) != m:
                return (
                    f"image_points.{i}",
                    f"{len(view)} pixels for {m} object points; give every target point's "
                    "pixel in every view",
                )
    return None


def calibrate_hand_eye_run(
    inputs: dict[str, Any], options: dict[str, Any], progress: Progress
) -> HandEyeRunResult:
    """Return the result of a hand-eye run (raising core's typed errors on bad data).

    inputs: arm_id, arm (its stored fields at submission), source, and for source "poses" the
    pose lists with optional object_points, image_points, K, dist. options: method, refine,
    and for the twin views, sigma_px, rendered, seed (inputs and options are the run's JSON
    columns)."""
    method = options["method"]
    twin: dict[str, Any] = {}
    P: Any
    uv: Any
    K: Any
    dist: Any
    if inputs["source"] == "twin":
        mm = twin_manipulator(ArmKinematics.from_json(inputs["arm"]))
        seed = options["seed"]
        progress(f"simulating {options['views']} eye-in-hand views", 0.05)
        views = hand_eye_views(
            np.random.default_rng(seed),
            views=options["views"],
            sigma_px=options["sigma_px"],
            rendered=options["rendered"],
            manipulator=mm,
        )
        E, C = views.T_base_ee, views.T_cam_target
        P, uv, K, dist = views.object_points, views.image_points, views.K, views.dist
        twin = {"seed": seed, "sigma_px": options["sigma_px"], "rendered": options["rendered"]}
    else:
        E = np.asarray(inputs["T_base_ee"], dtype=float)
        C = np.asarray(inputs["T_cam_target"], dtype=float)
        P = inputs.get("object_points")
        uv = inputs.get("image_points")
        K = inputs.get("K")
        dist = inputs.get("dist")
    progress("calibrating", 0.8)
    refine = bool(options["refine"]) and uv is not None
    result = calibrate_hand_eye(
        E,
        C,
        method=method,
        object_points=P if refine else None,
        image_points=uv if refine else None,
        K=K if refine else None,
        dist=dist if refine else None,
    )
    if inputs["source"] == "twin":
        # Scoring only: every method on the same views, and this result, against the truth.
        truth = views.true_X
        methods = []
        for m in METHODS:
            r = calibrate_hand_eye(E, C, method=m)
            error = hand_eye_error(m, r.X, truth, r.rotation_std_deg, r.translation_std_m)
            methods.append(HandEyeMethodRow.model_validate(error))
        twin["methods"] = methods
        error = hand_eye_error(
            result.method, result.X, truth, result.rotation_std_deg, result.translation_std_m
        )
        twin["truth"] = HandEyeMethodRow.model_validate(error)
    progress("done", 1.0)
    return HandEyeRunResult(
        kind="hand-eye",
        arm_id=inputs["arm_id"],
        source=inputs["source"],
        method=result.method,
        X=result.X.tolist(),
        covariance=result.covariance.tolist(),
        rotation_std_deg=result.rotation_std_deg,
        translation_std_m=result.translation_std_m,
        views=int(E.shape[0]),
        motions=result.motions,
        rotation_residuals_deg=result.rotation_residuals_deg.tolist(),
        translation_residuals_m=result.translation_residuals_m.tolist(),
        refined=result.refined,
        rms_px=result.rms_px,
        per_view_rms_px=(
            None if result.per_view_rms_px is None else result.per_view_rms_px.tolist()
        ),
        iterations=result.iterations,
        T_base_target=result.T_base_target.tolist(),
        **twin,
    )


def compute(session: Session, run: CalibrationRun, progress: Progress) -> HandEyeRunResult:
    """Return the result of a claimed hand-eye run (calibrate_hand_eye_run)."""
    del session  # the arm's fields were stored with the run
    return calibrate_hand_eye_run(run.inputs, run.options, progress)


def apply(session: Session, run: CalibrationRun, scene: SceneSync) -> ArmRead:
    """Set the run's arm's T_ee_camera from a succeeded hand-eye run and record it in the
    arm's history; return the arm. Applying the run the arm already has changes nothing (one
    conditional UPDATE, so concurrent applies record it once). Raises RunRefused: 409 when
    the arm was deleted."""
    del scene  # the scene draws arms from their joints, not their cameras
    if run.arm_id is None:
        raise RunRefused(409, f"the arm of run {run.id} was deleted")
    arm = found(session, Arm, run.arm_id, "arm")
    # Only the fields applying reads: a result is what its run stored, whatever version wrote it.
    result = run.result
    assert result is not None
    X = result["X"]
    changed = session.execute(
        update(Arm)
        .where(Arm.id == arm.id, or_(Arm.hand_eye_run_id.is_(None), Arm.hand_eye_run_id != run.id))
        .values(T_ee_camera=X, hand_eye_run_id=run.id, updated_at=utcnow())
        .execution_options(synchronize_session=False)
    )
    if rows_changed(changed) == 1:
        session.add(
            HandEyeCalibration(
                arm_id=arm.id,
                calibration_run_id=run.id,
                T_ee_camera=X,
                rotation_std_deg=result["rotation_std_deg"],
                translation_std_m=result["translation_std_m"],
                rms_px=result.get("rms_px"),
                method=result["method"],
            )
        )
    session.commit()
    session.refresh(arm)
    return arm_read(arm)
