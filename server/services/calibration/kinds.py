"""The table of calibration run kinds: for each, how a run of it is created from a request,
computed by a worker and applied to what it calibrated, and the schema of its result. The
routes, the executor and apply look a run's kind up here."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel
from sqlalchemy.orm import Session

import server.services.calibration.hand_eye as hand_eye
import server.services.calibration.intrinsics as intrinsics
import server.services.calibration.network as network
import server.services.calibration.placement as placement
import server.services.calibration.projector as projector
from core.errors import IntspaceError
from server.db.models import CalibrationRun, Camera, Projector
from server.schemas.manipulation import ArmRead
from server.services.calibration._shared import Progress, RunContext
from server.services.scene_sync import SceneSync

# What applying a run changed: a camera, cameras, an arm (as the API shows it) or a projector.
Applied = Camera | list[Camera] | ArmRead | Projector


@dataclass(frozen=True)
class RunKind:
    """One kind of calibration run (CalibrationRun.kind).

    `create(body, context)` returns the unsaved queued run of a POST /calibration-runs body of
    this kind (None: runs of the kind are made by another route), `compute(session, run,
    progress)` the result a worker stores (a `result`), `apply(session, run, scene)` what the
    applied run changed (a camera, cameras, an arm or a projector); `result` is the schema of
    the stored result. create and apply raise RunRefused, compute core's typed errors."""

    name: str
    result: type[BaseModel]
    compute: Callable[[Session, CalibrationRun, Progress], BaseModel]
    apply: Callable[[Session, CalibrationRun, SceneSync], Applied]
    create: Callable[[Any, RunContext], CalibrationRun] | None = None


KINDS: dict[str, RunKind] = {
    kind.name: kind
    for kind in (
        # Made by POST /calibration-runs (correspondences) or its /upload (photos).
        RunKind(
            intrinsics.KIND,
            intrinsics.Result,
            intrinsics.compute,
            intrinsics.apply,
            intrinsics.create,
        ),
        RunKind(network.KIND, network.Result, network.compute, network.apply, network.create),
        RunKind(hand_eye.KIND, hand_eye.Result, hand_eye.compute, hand_eye.apply, hand_eye.create),
        RunKind(
            projector.KIND, projector.Result, projector.compute, projector.apply, projector.create
        ),
        # Made finished by POST /cameras/{id}/placement.
        RunKind(placement.KIND, placement.Result, placement.compute, placement.apply),
    )
}


class UnknownRunKind(IntspaceError):
    """A run of a kind this service does not know (stored by a newer version)."""


def kind_of(name: str) -> RunKind:
    """Return the kind called `name`; raise UnknownRunKind naming the known ones."""
    try:
        return KINDS[name]
    except KeyError:
        raise UnknownRunKind(
            f"this service knows no calibration runs of kind {name!r} (it knows "
            f"{', '.join(sorted(KINDS))})"
        ) from None
