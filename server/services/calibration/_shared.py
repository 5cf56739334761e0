"""What every kind of calibration run shares: the progress callback, the typed refusal, what a
run is created from, and the camera columns an applied run sets."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

from sqlalchemy import or_, update
from sqlalchemy.orm import Session

from server.db.base import Base, utcnow
from server.db.models import CalibrationRun, Camera, CameraCalibration
from server.services.jobs import rows_changed

if TYPE_CHECKING:
    from server.services.twin import Twin

M = TypeVar("M", bound=Base)

# Reports how far a run has come: (stage, fraction of the whole run 0-1); may raise to stop it.
Progress = Callable[[str, float], None]


def no_progress(stage: str, fraction: float) -> None:
    """Report nothing (a run computed outside the executor)."""
    del stage, fraction


class RunRefused(Exception):
    """A run that cannot be created or applied: the HTTP `status`, the `reason` and, when one
    field of the request is at fault, that `field` and where it was (`location`: body, form,
    path, query)."""

    def __init__(
        self, status: int, reason: str, field: str | None = None, location: str = "body"
    ) -> None:
        super().__init__(reason)
        self.status = status
        self.field = field
        self.location = location


@dataclass(frozen=True)
class RunContext:
    """What creating a run may consult besides its request: the database session, the running
    digital twin (None without simulation) and the twin's seed (the default of a seeded run)."""

    session: Session
    twin: Twin | None
    twin_seed: int


def existing(session: Session, model: type[M], id: int | None, field: str) -> M:
    """Return row `id` of `model`; raise RunRefused (422 naming `field`) when there is none."""
    row = None if id is None else session.get(model, id)
    if row is None:
        table = model.__tablename__.rstrip("s")
        raise RunRefused(422, f"no {table} with id {id}", field)
    return row


def found(session: Session, model: type[M], id: int, what: str) -> M:
    """Return row `id` of `model`; raise RunRefused (404 naming `what`) when there is none."""
    row = session.get(model, id)
    if row is None:
        raise RunRefused(404, f"no {what} with id {id}")
    return row


def run_camera(session: Session, run: CalibrationRun, what: str, advice: str) -> Camera:
    """Return the camera a run calibrated, checking it still has the run's image size (`what`
    the run did, a format of width and height, e.g. "calibrated {width}x{height} images";
    `advice` what to do when it has not). Raises RunRefused: 409 when the camera was deleted
    or resized, 404 when it is gone from under the run."""
    assert run.result is not None
    if run.camera_id is None:
        raise RunRefused(409, f"the camera of run {run.id} was deleted")
    camera = found(session, Camera, run.camera_id, "camera")
    width, height = run.result["image_size"]
    if (width, height) != (camera.width, camera.height):
        raise RunRefused(
            409,
            f"run {run.id} {what.format(width=width, height=height)} but camera {camera.id} is "
            f"{camera.width}x{camera.height}; {advice}",
        )
    return camera


def set_camera_calibration(
    session: Session, camera_id: int, run_id: int, values: dict[str, Any]
) -> bool:
    """Set a camera's calibration from run `run_id` unless it is already that run's; return
    whether it changed. One conditional UPDATE, so two concurrent applies of one run change
    the camera (and add to its history) once: applying is idempotent."""
    result = session.execute(
        update(Camera)
        .where(
            Camera.id == camera_id,
            or_(Camera.calibration_run_id.is_(None), Camera.calibration_run_id != run_id),
        )
        .values(status="calibrated", calibration_run_id=run_id, updated_at=utcnow(), **values)
        .execution_options(synchronize_session=False)
    )
    return rows_changed(result) == 1


def camera_history_entry(
    camera_id: int,
    run_id: int,
    K: Any,
    dist: Any,
    rms: float | None,
    image_size: list[int],
) -> CameraCalibration:
    """Return the entry of a camera's calibration history recording run `run_id`."""
    width, height = image_size
    return CameraCalibration(
        camera_id=camera_id,
        calibration_run_id=run_id,
        K=K,
        dist=dist,
        rms=rms,
        image_width=width,
        image_height=height,
    )
