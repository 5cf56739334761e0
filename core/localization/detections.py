"""One camera frame's detections for the tracker: the robot's marker and the people, unlabelled.

`detect_frame` is what the twin's loop and a camera node both call on each image: the robot's
top marker (core.localization.detect.detect_marker) is a "robot" detection of a point at the
marker's height; the people come from a person detector behind the `PeopleDetector` interface:

* `BackgroundPeople` (a `PersonDetector`, background subtraction): each foreground blob that
  does not hold the marker is a "person" detection: with the camera's calibration, the image of
  the foot of the body's axis (PersonDetector.detect_bodies, a cylinder fitted to the
  silhouette), else the blob's lowest point. What the twin's cameras use: their people are
  uniformly coloured cylinders no detector trained on photographs knows.
* `core.localization.ssd_people.SsdPeopleDetector` (a neural detector trained on photographs of
  people): each box's foot point (core.localization.boxes.box_foot). What real cameras use.

The result is the tracker's input (core.localization.tracking): pixel, pixel covariance, kind
and the height of the point the pixel measures.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from core.localization.cameras import NetworkCamera
from core.localization.detect import MarkerDetectorConfig, PersonDetector, detect_marker

Array = NDArray[np.float64]

# A blob whose fitted body is shorter than this (m) is not a standing person: the robot's body
# seen by a camera that missed its marker, a pet, a bag.
MIN_PERSON_HEIGHT_M = 1.0


@dataclass(frozen=True)
class FrameDetection:
    """One detection: kind ("robot" or "person"), distorted pixel (2,), its covariance (2, 2)
    px^2, height (m) of the point the pixel measures, the blob's or box's extent (x, y, w, h)
    px, and a neural detector's score in [0, 1] (None for detectors without one)."""

    kind: str
    pixel: Array
    cov: Array
    height: float
    bbox: tuple[int, int, int, int] | None = None
    score: float | None = None

    def to_dict(self) -> dict[str, object]:
        """Return the detection as JSON-ready values (no "bbox" key without a box)."""
        out: dict[str, object] = {
            "kind": self.kind,
            "pixel": [float(v) for v in self.pixel],
            "cov": np.asarray(self.cov, dtype=float).tolist(),
            "height": float(self.height),
        }
        if self.bbox is not None:
            out["bbox"] = [int(v) for v in self.bbox]
        if self.score is not None:
            out["score"] = float(self.score)
        return out


@runtime_checkable
class PeopleDetector(Protocol):
    """Finds the people in one camera's frames (one instance per camera: it may keep state,
    such as a learnt background)."""

    def detect_people(
        self,
        image: NDArray[np.uint8],
        *,
        camera: NetworkCamera | None = None,
        robot_pixels: Sequence[Array] = (),
    ) -> list[FrameDetection]:
        """Return the "person" detections in a BGR image (H, W, 3). camera: its calibration
        (None: unknown); robot_pixels: where the robot's markers were found in this image (a
        detector that cannot tell the robot's body from a person leaves out what holds one)."""
        ...


class BackgroundPeople:
    """People as the foreground blobs of a learnt background (`PersonDetector`).

    A blob around a robot marker is the robot's body, not a person, and so is a blob whose
    fitted body is shorter than MIN_PERSON_HEIGHT_M. With the camera's calibration a person is
    located at the axis of their body rather than at the near edge of the silhouette (strongly
    preferred: the edge is a body radius off, towards the camera)."""

    def __init__(self, model: PersonDetector) -> None:
        self.model = model

    def detect_people(
        self,
        image: NDArray[np.uint8],
        *,
        camera: NetworkCamera | None = None,
        robot_pixels: Sequence[Array] = (),
    ) -> list[FrameDetection]:
        """Return the people among the foreground blobs of `image` (see the class)."""

        def holds_marker(box: tuple[int, int, int, int]) -> bool:
            x, y, w, h = box
            return any(x <= u <= x + w and y <= v <= y + h for u, v in robot_pixels)

        out: list[FrameDetection] = []
        if camera is None:
            for p in self.model.detect(image):
                box = _box(p.bbox)
                if not holds_marker(box):
                    out.append(FrameDetection("person", p.foot_pixel, p.cov, 0.0, box))
            return out
        for b in self.model.detect_bodies(image, camera):
            box = _box(b.bbox)
            if holds_marker(box) or b.body_height < MIN_PERSON_HEIGHT_M:
                continue
            out.append(FrameDetection("person", b.pixel, b.cov, float(b.height), box))
        return out


def detect_frame(
    image: NDArray[np.uint8],
    *,
    marker: MarkerDetectorConfig | None = None,
    marker_height: float = 0.0,
    people: PersonDetector | PeopleDetector | None = None,
    camera: NetworkCamera | None = None,
    mast: MarkerDetectorConfig | None = None,
) -> list[FrameDetection]:
    """Return the robot and people detected in one BGR image.

    marker: the robot's marker settings (None: no robot detection) and marker_height its
    height above the floor (m); people: a person detector (a `PersonDetector` with its
    background learnt is used as `BackgroundPeople`; None: no people); camera: the camera's
    calibration; mast: the settings of the robot's mast marker, when the robot carries one (a
    mast reaches a person's height, so a blob around it is the robot too). A background
    detector's learnt background also tells the marker detector what red things belong to the
    room, and with the camera and the marker's radius (`marker.radius`) the marker must have the
    size and shape of its disc's image at `marker_height` (core.localization.detect.detect_marker).
    """
    out: list[FrameDetection] = []
    background = people.background() if isinstance(people, PersonDetector) else None
    found = None
    if marker is not None:
        found = detect_marker(
            image, marker, background=background, camera=camera, height=marker_height
        )
    if found is not None:
        out.append(FrameDetection("robot", found.pixel, found.cov, float(marker_height)))
    if people is None:
        return out

    robot_points = [] if found is None else [found.pixel]
    if mast is not None:
        top = detect_marker(image, mast, background=background)
        if top is not None:
            robot_points.append(top.pixel)
    detector = BackgroundPeople(people) if isinstance(people, PersonDetector) else people
    out += detector.detect_people(image, camera=camera, robot_pixels=robot_points)
    return out


def _box(bbox: object) -> tuple[int, int, int, int]:
    x, y, w, h = (int(v) for v in bbox)  # type: ignore[attr-defined]
    return (x, y, w, h)
