"""What the trackers take in: detections to ingest, the camera frames they make (one camera,
one capture time), what `ingest` did, and the delays of the frames' stages. Times are Unix
seconds on the service's clock."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from server.delays import StageDelays


@dataclass(frozen=True)
class DetectionIn:
    """One detection to ingest: camera id, capture time (s), distorted pixel (2,), its 2x2
    covariance px^2, kind, height (m) of the measured point, label or None; a detector's box
    (x0, y0, x1, y1), score, cut sides and appearance descriptor
    (core.localization.appearance) when it came as a box, and whether it measures a floor
    position (`tracked` False: a box whose bottom is cut, stored only)."""

    camera_id: int
    t: float
    pixel: tuple[float, float]
    cov: tuple[tuple[float, float], tuple[float, float]]
    kind: str
    height: float
    label: str | None = None
    box: tuple[float, float, float, float] | None = None
    score: float | None = None
    cut: tuple[str, ...] | None = None
    appearance: tuple[float, ...] | None = None
    tracked: bool = True


@dataclass(frozen=True)
class CameraFrame:
    """One camera frame's detections, ready for the tracker; `appearances` (D, F): their
    appearance descriptors, a row of zeros for a detection without one, or None when none has
    one."""

    camera_id: int
    t: float
    pixels: np.ndarray
    cov: np.ndarray
    heights: np.ndarray
    kinds: list[str]
    labels: list[str | None]
    ids: tuple[int, ...] = ()
    appearances: np.ndarray | None = None


@dataclass(frozen=True)
class IngestResult:
    """What `ingest` did: detections stored, camera frames queued, frames refused as late."""

    stored: int
    frames: int
    late: int


class FrameDelays(StageDelays):
    """The delays (s) of the camera frames a tracker processed, the newest `keep`: from capture
    to arrival at the service (the sender's detection and upload, or the twin's rendering and
    detection), arrival to release by the reorder buffer, and release to the end of the
    tracker's update and the live targets' change."""

    def __init__(self, keep: int = 20_000) -> None:
        super().__init__(("capture to arrival", "reorder wait", "tracker update"), keep)

    def frame(self, t: float, arrived: float, released: float, done: float) -> None:
        """Record one frame captured at t, arrived, released and processed at those times."""
        self.add(arrived - t, max(0.0, released - arrived), done - released)


def empty_frame(camera_id: int, t: float) -> CameraFrame:
    """Return a camera frame captured at `t` in which nothing was detected."""
    return CameraFrame(camera_id, t, np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0), [], [])


def camera_frames(
    detections: Sequence[DetectionIn], ids: Sequence[int] | None = None
) -> list[CameraFrame]:
    """Return the detections split into camera frames (same camera and capture time), in time
    order; `ids` (one per detection) are their stored rows' ids, when known."""
    by_frame: dict[tuple[int, float], list[DetectionIn]] = {}
    row_ids: dict[tuple[int, float], list[int]] = {}
    for k, d in enumerate(detections):
        by_frame.setdefault((d.camera_id, d.t), []).append(d)
        if ids is not None:
            row_ids.setdefault((d.camera_id, d.t), []).append(int(ids[k]))
    frames = []
    for (camera_id, t), dets in sorted(by_frame.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        frames.append(
            CameraFrame(
                camera_id=camera_id,
                t=t,
                pixels=np.array([d.pixel for d in dets], dtype=np.float64).reshape(-1, 2),
                cov=np.array([d.cov for d in dets], dtype=np.float64).reshape(-1, 2, 2),
                heights=np.array([d.height for d in dets], dtype=np.float64),
                kinds=[d.kind for d in dets],
                labels=[d.label for d in dets],
                ids=tuple(row_ids.get((camera_id, t), ())),
                appearances=appearances_of(dets),
            )
        )
    return frames


def appearances_of(detections: Sequence[DetectionIn]) -> np.ndarray | None:
    """Return the detections' appearance descriptors (D, F), zeros for those without one (or
    of another length than the first), or None when none has one."""
    given = [d.appearance for d in detections if d.appearance is not None]
    if not given:
        return None
    size = len(given[0])
    out = np.zeros((len(detections), size))
    for k, d in enumerate(detections):
        if d.appearance is not None and len(d.appearance) == size:
            out[k] = d.appearance
    return out
