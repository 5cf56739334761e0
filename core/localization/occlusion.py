"""Which tracks a camera can see (core.localization.tracking): past the walls and furniture of
the floor plan (`visible`), and not hidden behind another track's body (`behind_a_body`). A
camera is expected to detect only the bodies it can see, and takes detections only for them."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from core.localization.association import largest_variance
from core.localization.cameras import NetworkCamera
from core.localization.occluders import Occluders, line_of_sight
from core.localization.track_table import TrackTable
from core.localization.tracker_config import TrackerConfig


def visible(
    cam: NetworkCamera, tracks: TrackTable, occluders: Occluders, cfg: TrackerConfig
) -> NDArray[np.bool_]:
    """Return whether `cam` has a clear line of sight (past the occluders) to some of each
    track's body: the top of its axis, body_height (a robot: the height of its last
    detection), as a camera that sees any of a body may detect it, at the predicted
    position or at any of four points around it, body_radius plus up to 0.3 m of its
    position's uncertainty (two standard deviations) away: a body beside a tall cabinet
    whose prediction falls just behind it is still seen."""
    T = len(tracks)
    z = np.array(
        [
            hh if k == "robot" else cfg.body_height
            for k, hh in zip(tracks.kinds, tracks.height, strict=True)
        ]
    )
    spread = 2.0 * np.sqrt(np.maximum(largest_variance(tracks.P[:, :2, :2]), 0.0))
    r = cfg.body_radius + np.minimum(spread, 0.3)
    ring = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    xy = tracks.x[:, None, :2] + r[:, None, None] * ring[None]  # (T, 5, 2)
    pts = np.concatenate([xy, np.broadcast_to(z[:, None, None], (T, 5, 1))], axis=2)
    clear = line_of_sight(cam.center[None], pts.reshape(-1, 3), occluders)[0]
    return np.asarray(clear.reshape(T, 5).any(axis=1), dtype=bool)


def behind_a_body(
    cam: NetworkCamera,
    tracks: TrackTable,
    rows: NDArray[np.intp],
    lost: NDArray[np.bool_],
    cfg: TrackerConfig,
) -> NDArray[np.bool_]:
    """Return whether each track of `rows` stands behind another track's body as `cam`
    sees it: on the floor, the other is nearer the camera, within two body radii of the
    line of sight at its own range, and near enough that its body (body_height tall) hides
    some of this one (from a camera at height H, a body at range d covers the floor out to
    d H / (H - body_height)). Robots are too low to hide anybody, and a lost track (`lost`
    (T,), waiting to be recognised: core.localization.recognition) stands nowhere."""
    others = np.array([k != "robot" for k in tracks.kinds], dtype=bool)
    others &= ~lost
    out = np.zeros(rows.size, dtype=bool)
    if others.sum() == 0:
        return out
    c = cam.center[:2]
    H = float(cam.center[2])
    a = tracks.x[rows, :2] - c  # (n, 2)
    b = tracks.x[others, :2] - c  # (m, 2)
    da = np.linalg.norm(a, axis=1)
    db = np.linalg.norm(b, axis=1)
    reach = db * H / (H - cfg.body_height) if H > cfg.body_height else np.full(db.shape, np.inf)
    along = a @ b.T / np.maximum(da[:, None], 1e-9)  # (n, m) b's range along a's sight line
    across = np.abs(a[:, 0:1] * b[None, :, 1] - a[:, 1:2] * b[None, :, 0]) / np.maximum(
        da[:, None], 1e-9
    )
    nearer = (db[None] < da[:, None] - 1e-6) & (along > 0)
    covers = (across < 2.0 * cfg.body_radius) & (da[:, None] <= reach[None])
    out = np.any(nearer & covers, axis=1)
    return out
