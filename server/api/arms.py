"""Arms on robots: kinematic model (DH parameters, joint limits, tool, mount), eye-in-hand
camera, hand-eye transform and its history; hand-eye calibration runs of an arm."""

from __future__ import annotations

import secrets
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Query, status
from sqlalchemy import or_, select, update

from server.api._crud import apply_changes, check_references, get_or_404, paginate
from server.api.deps import PageDep, ReadAccess, SessionDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.db.base import utcnow
from server.db.models import Arm, CalibrationRun, Camera, HandEyeCalibration, Robot
from server.schemas.calibration import CalibrationRunRead
from server.schemas.common import MAX_ID, Page
from server.schemas.manipulation import (
    ArmCreate,
    ArmRead,
    ArmUpdate,
    HandEyeCalibrationRead,
    HandEyeRunCreate,
)
from server.services.manipulation import (
    arm_model_problem,
    arm_values,
    closed_form,
    pose_pairs_problem,
)

router = APIRouter(prefix="/arms", tags=["arms"], responses=PROBLEM_RESPONSES)
ArmId = Annotated[int, Path(ge=1, le=MAX_ID)]
_COLUMNS = tuple(name for name in ArmRead.model_fields if name != "closed_form")


def arm_read(arm: Arm) -> ArmRead:
    """Return an arm as the API shows it (with whether it has the closed-form IK)."""
    data: dict[str, Any] = {name: getattr(arm, name) for name in _COLUMNS}
    return ArmRead.model_validate({**data, "closed_form": closed_form(arm_values(arm))})


def _check_unique_name(session, arm: Arm | None, changes: dict[str, Any]) -> None:
    name = changes.get("name", getattr(arm, "name", None))
    robot_id = changes.get("robot_id", getattr(arm, "robot_id", None))
    stmt = select(Arm.id).where(Arm.name == name, Arm.robot_id == robot_id)
    if arm is not None:
        stmt = stmt.where(Arm.id != arm.id)
    clash = session.scalar(stmt.limit(1))
    if clash is not None:
        raise FieldProblem(409, "name", f"arm {clash} is already called {name!r} on this robot")


def _check_model(arm: Arm | None, changes: dict[str, Any]) -> None:
    keys = ("dh", "limits", "tool", "home", "T_robot_arm", "T_ee_camera")
    merged = {k: changes[k] if k in changes else getattr(arm, k, None) for k in keys}
    problem = arm_model_problem(merged)
    if problem is not None:
        raise FieldProblem(422, *problem)


def _references(changes: dict[str, Any]) -> dict:
    return {
        "robot_id": (Robot, changes.get("robot_id")),
        "camera_id": (Camera, changes.get("camera_id")),
    }


@router.get("", response_model=Page[ArmRead], dependencies=[ReadAccess])
def list_arms(
    session: SessionDep,
    page: PageDep,
    robot_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
):
    """Return a page of arms, optionally of one robot."""
    stmt = select(Arm).order_by(Arm.id)
    if robot_id is not None:
        stmt = stmt.where(Arm.robot_id == robot_id)
    listing = paginate(session, stmt, page)
    listing["items"] = [arm_read(arm) for arm in listing["items"]]
    return listing


@router.post(
    "", response_model=ArmRead, status_code=status.HTTP_201_CREATED, dependencies=[WriteAccess]
)
def create_arm(body: ArmCreate, session: SessionDep):
    """Attach an arm to a robot (names are unique on a robot: 409 on a clash). Kinematic
    fields left out are the twin's arm's."""
    data = body.model_dump()
    check_references(session, _references(data))
    _check_unique_name(session, None, data)
    _check_model(None, data)
    arm = Arm(**data)
    session.add(arm)
    session.commit()
    return arm_read(arm)


@router.get("/{arm_id}", response_model=ArmRead, dependencies=[ReadAccess])
def get_arm(arm_id: ArmId, session: SessionDep):
    """Return one arm."""
    return arm_read(get_or_404(session, Arm, arm_id, "arm"))


@router.patch("/{arm_id}", response_model=ArmRead, dependencies=[WriteAccess])
def update_arm(arm_id: ArmId, body: ArmUpdate, session: SessionDep):
    """Change the fields given (null clears an optional one). A T_ee_camera typed in replaces
    the applied hand-eye run's (the arm then has no hand-eye run)."""
    arm = get_or_404(session, Arm, arm_id, "arm")
    changes = body.model_dump(exclude_unset=True)
    for key in ("robot_id", "name", "dh", "limits", "tool", "home", "T_robot_arm"):
        if key in changes and changes[key] is None:
            raise FieldProblem(422, key, f"{key} cannot be cleared; give a value")
    check_references(session, _references(changes))
    _check_unique_name(session, arm, changes)
    _check_model(arm, changes)
    if "T_ee_camera" in changes:
        changes["hand_eye_run_id"] = None
    apply_changes(arm, changes)
    session.commit()
    return arm_read(arm)


@router.delete("/{arm_id}", status_code=status.HTTP_204_NO_CONTENT, dependencies=[WriteAccess])
def delete_arm(arm_id: ArmId, session: SessionDep) -> None:
    """Delete an arm and its hand-eye history (its runs and tasks stay, unassigned)."""
    session.delete(get_or_404(session, Arm, arm_id, "arm"))
    session.commit()


@router.get(
    "/{arm_id}/hand-eye-calibrations",
    response_model=Page[HandEyeCalibrationRead],
    dependencies=[ReadAccess],
)
def list_hand_eye_calibrations(arm_id: ArmId, session: SessionDep, page: PageDep):
    """Return the arm's hand-eye history (the runs applied to it), newest first."""
    get_or_404(session, Arm, arm_id, "arm")
    stmt = (
        select(HandEyeCalibration)
        .where(HandEyeCalibration.arm_id == arm_id)
        .order_by(HandEyeCalibration.id.desc())
    )
    return paginate(session, stmt, page)


@router.get(
    "/{arm_id}/calibration-runs",
    response_model=Page[CalibrationRunRead],
    dependencies=[ReadAccess],
)
def list_arm_runs(arm_id: ArmId, session: SessionDep, page: PageDep):
    """Return the arm's hand-eye calibration runs, newest first."""
    get_or_404(session, Arm, arm_id, "arm")
    stmt = (
        select(CalibrationRun)
        .where(CalibrationRun.arm_id == arm_id)
        .order_by(CalibrationRun.id.desc())
    )
    return paginate(session, stmt, page)


# --------------------------------------------------------------------------------------------
# Hand-eye runs (POST /calibration-runs with kind "hand-eye", and their apply)


def hand_eye_run(body: HandEyeRunCreate, session, twin_running: bool) -> CalibrationRun:
    """Return the (unsaved) queued run of a hand-eye request, refusing what it could not
    calibrate: 409 without the twin for source "twin"; 422 naming the field for an arm the
    twin cannot simulate, pose pairs whose motions are degenerate or whose pixels do not
    match, refinement without K."""
    check_references(session, {"arm_id": (Arm, body.arm_id)})
    arm = session.get(Arm, body.arm_id)
    assert arm is not None
    values = arm_values(arm)
    options: dict[str, Any] = {"method": body.method, "refine": body.refine}
    inputs: dict[str, Any] = {"arm_id": arm.id, "arm": values, "source": body.source}
    if body.source == "twin":
        if not twin_running:
            raise HTTPException(
                status.HTTP_409_CONFLICT,
                detail="a twin hand-eye run simulates the twin's arm and camera; start the "
                "service with INTSPACE_SIMULATION=true, or upload your arm's pose pairs "
                "(source 'poses')",
            )
        if not closed_form(values):
            raise FieldProblem(
                422,
                "arm_id",
                f"arm {arm.id} is not of the Puma type whose closed-form inverse kinematics "
                "places the twin's views; calibrate it from pose pairs (source 'poses')",
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
            raise FieldProblem(422, *problem)
        K, dist = body.K, body.dist
        if body.image_points is not None and K is None:
            camera = session.get(Camera, arm.camera_id) if arm.camera_id is not None else None
            if camera is None or camera.K is None:
                raise FieldProblem(
                    422,
                    "K",
                    "refining by reprojection needs the camera's K: give K (and dist), or "
                    "give the arm a calibrated eye-in-hand camera",
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
        kind="hand-eye",
        source=body.source,
        camera_id=arm.camera_id,
        arm_id=arm.id,
        inputs=inputs,
        options=options,
    )


def apply_hand_eye_run(run: CalibrationRun, session) -> ArmRead:
    """Set the run's arm's T_ee_camera from a succeeded hand-eye run and record it in the
    arm's history; applying the run the arm already has changes nothing (one conditional
    UPDATE, so concurrent applies record it once)."""
    if run.arm_id is None:
        raise HTTPException(status.HTTP_409_CONFLICT, detail=f"the arm of run {run.id} was deleted")
    arm = get_or_404(session, Arm, run.arm_id, "arm")
    assert run.result is not None
    X = run.result["X"]
    changed = session.execute(
        update(Arm)
        .where(Arm.id == arm.id, or_(Arm.hand_eye_run_id.is_(None), Arm.hand_eye_run_id != run.id))
        .values(T_ee_camera=X, hand_eye_run_id=run.id, updated_at=utcnow())
        .execution_options(synchronize_session=False)
    )
    if changed.rowcount == 1:
        session.add(
            HandEyeCalibration(
                arm_id=arm.id,
                calibration_run_id=run.id,
                T_ee_camera=X,
                rotation_std_deg=run.result["rotation_std_deg"],
                translation_std_m=run.result["translation_std_m"],
                rms_px=run.result.get("rms_px"),
                method=run.result["method"],
            )
        )
    session.commit()
    session.refresh(arm)
    return arm_read(arm)
