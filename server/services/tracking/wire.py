"""What the processes sharing one database send each other about tracking (LISTEN/NOTIFY,
server.services.fanout): the channels, a camera frame as a notification item and back, and
stored detections' ids as runs."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np

from server.services.fanout import PAYLOAD_LIMIT
from server.services.tracking.ingest import CameraFrame, empty_frame

TARGETS_CHANNEL = "intspace_targets"
DETECTIONS_CHANNEL = "intspace_detections"
CONTROL_CHANNEL = "intspace_tracker_control"

# A camera frame sent to the space's tracker in another process is sent whole when its
# notification item stays below this many bytes (else by its rows' ids, read back there).
_FRAME_ITEM_BYTES = PAYLOAD_LIMIT - 200


def frame_item(f: CameraFrame) -> dict[str, Any] | None:
    """Return a camera frame as a notification item: {"c": camera, "t": time} for an empty
    frame, with its stored rows' "ids", pixels, covariances (xx, xy, yy), heights, kinds and
    labels (and appearance descriptors "a", when they have some) for the others; None when it
    is too large for one notification."""
    item: dict[str, Any] = {"c": f.camera_id, "t": f.t}
    if not f.pixels.shape[0]:
        return item
    item.update(
        ids=list(f.ids),
        px=f.pixels.tolist(),
        cov=f.cov.reshape(-1, 4)[:, [0, 1, 3]].tolist(),
        h=f.heights.tolist(),
        k=list(f.kinds),
        l=list(f.labels),
    )
    if f.appearances is not None:
        item["a"] = f.appearances.tolist()
    if len(json.dumps(item, separators=(",", ":"))) > _FRAME_ITEM_BYTES:
        return None
    return item


def frame_of_item(item: dict[str, Any]) -> CameraFrame:
    """Return the camera frame of a notification item (`frame_item`)."""
    if "px" not in item:
        return empty_frame(int(item["c"]), float(item["t"]))
    c = np.asarray(item["cov"], dtype=np.float64).reshape(-1, 3)
    cov = np.stack([c[:, [0, 1]], c[:, [1, 2]]], axis=1)
    return CameraFrame(
        camera_id=int(item["c"]),
        t=float(item["t"]),
        pixels=np.asarray(item["px"], dtype=np.float64).reshape(-1, 2),
        cov=cov,
        heights=np.asarray(item["h"], dtype=np.float64),
        kinds=[str(k) for k in item["k"]],
        labels=[None if v is None else str(v) for v in item["l"]],
        ids=tuple(int(i) for i in item["ids"]),
        appearances=None if "a" not in item else np.asarray(item["a"], dtype=np.float64),
    )


def id_runs(ids: Sequence[int]) -> list[list[int]]:
    """Return the sorted ids as runs [first, last] of consecutive ids."""
    runs: list[list[int]] = []
    for i in sorted(set(ids)):
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return runs
