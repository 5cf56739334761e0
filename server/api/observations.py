"""Localisation of batched detections: POST /observations -> floor positions with covariance."""

from __future__ import annotations

from typing import Annotated

import numpy as np
from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse

from core.localization import PointStatus, locate_ml
from server.api.deps import SessionDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.schemas.localization import ObservationBatch, PositionBatch
from server.services.targets import LiveTargets
from server.services.twin import registry_cameras

router = APIRouter(tags=["localization"], responses=PROBLEM_RESPONSES)

_STATUS = {
    PointStatus.OK: "ok",
    PointStatus.TOO_FEW_CAMERAS: "too_few_cameras",
    PointStatus.DEGENERATE: "degenerate",
    PointStatus.BEHIND_CAMERA: "behind_camera",
}


async def get_targets(request: Request) -> LiveTargets | None:
    """Return the live targets store (None before the app started)."""
    return getattr(request.app.state, "targets", None)


@router.post(
    "/observations",
    response_model=PositionBatch,
    dependencies=[WriteAccess],
)
def post_observations(
    body: ObservationBatch,
    session: SessionDep,
    live: Annotated[LiveTargets | None, Depends(get_targets)],
):
    """Return the floor position of each (target, t) of the batch: its detections from every
    camera fused by maximum likelihood on the plane Z = height (core.localization.locate_ml).
    Every camera must have intrinsics and a pose; a camera may see a (target, t) once."""
    obs = body.observations
    camera_ids = sorted({o.camera_id for o in obs})
    cameras, refused = registry_cameras(session, camera_ids)
    for index, o in enumerate(obs):
        if o.camera_id in refused:
            raise FieldProblem(
                422,
                f"observations.{index}.camera_id",
                f"{refused[o.camera_id]}; calibrate and pose it before sending its detections",
            )
    column = {cid: k for k, cid in enumerate(camera_ids)}
    groups: dict[tuple[str | None, float, float], int] = {}
    n = len(obs)
    cam = np.empty(n, dtype=np.intp)
    group = np.empty(n, dtype=np.intp)
    pix = np.empty((n, 2))
    cov = np.empty((n, 2, 2))
    for i, o in enumerate(obs):
        key = (o.target, o.t, o.height)
        g = groups.get(key)
        if g is None:
            g = groups[key] = len(groups)
        cam[i], group[i] = column[o.camera_id], g
        pix[i] = o.pixel
        if o.cov is not None:
            cov[i] = o.cov
        else:
            s2 = (o.sigma_px or 1.0) ** 2
            cov[i] = ((s2, 0.0), (0.0, s2))
    C, B = len(camera_ids), len(groups)
    pair = cam * B + group
    _, first, counts = np.unique(pair, return_index=True, return_counts=True)
    if np.any(counts > 1):
        i = int(first[np.argmax(counts > 1)])
        raise FieldProblem(
            422,
            f"observations.{i}",
            f"camera {obs[i].camera_id} has more than one detection of target "
            f"{obs[i].target!r} at t = {obs[i].t}; send one per camera, target and time",
        )
    keys = list(groups)
    heights = np.array([k[2] for k in keys])
    xy = np.full((B, 2), np.nan)
    xy_cov = np.full((B, 2, 2), np.nan)
    status = np.zeros(B, dtype=np.int8)
    n_cam = np.zeros(B, dtype=np.int64)
    order = [cameras[cid] for cid in camera_ids]
    for h in np.unique(heights):
        sel = np.flatnonzero(heights == h)
        remap = np.full(B, -1)
        remap[sel] = np.arange(sel.size)
        mine = remap[group] >= 0
        pixels = np.zeros((C, sel.size, 2))
        pixel_cov = np.tile(np.eye(2), (C, sel.size, 1, 1))
        visible = np.zeros((C, sel.size), dtype=bool)
        idx = (cam[mine], remap[group[mine]])
        pixels[idx], pixel_cov[idx], visible[idx] = pix[mine], cov[mine], True
        est = locate_ml(order, pixels, float(h), visible=visible, pixel_cov=pixel_cov)
        xy[sel], xy_cov[sel] = est.xy, est.cov
        status[sel], n_cam[sel] = est.status, est.n_cameras
    positions = []
    for b, (target, t, _) in enumerate(keys):
        ok = status[b] == PointStatus.OK
        p_xy = xy[b].tolist() if ok else None
        p_cov = xy_cov[b].tolist() if ok else None
        positions.append(
            {
                "target": target,
                "t": t,
                "xy": p_xy,
                "cov": p_cov,
                "n_cameras": int(n_cam[b]),
                "estimator": "ml",
                "status": _STATUS[PointStatus(int(status[b]))],
            }
        )
        if ok and target is not None and live is not None:
            live.update(target, "external", t, p_xy, p_cov)
    return JSONResponse({"positions": positions})
