"""The settings of the tracker (core.localization.tracking), and the constants of its gates and
life cycle."""

from __future__ import annotations

import math
from dataclasses import dataclass

from core.errors import InvalidInput

# Chi-square quantiles with 2 degrees of freedom: -2 ln(1 - p).
CHI2_2DOF_99 = 9.2103
CHI2_2DOF_999 = 13.816
CHI2_2DOF_999999 = 27.631
# A tentative track is dropped after this many frame intervals of the camera that last saw it
# without an update (two frames without it, and half an interval of jitter), and must be
# confirmed within this many (what the default one-second window holds of a camera at 10 frames
# a second), when those are longer than tentative_timeout and confirm_window.
TENTATIVE_GAPS = 2.5
CONFIRM_GAPS = 10.0
# A pause longer than this (s) between two frames of a camera is a silence (a node restarted, a
# stream that dropped), not its frame rate: it is left out of the camera's mean interval.
MAX_FRAME_GAP = 1.0
# A lost body recognised by its look (core.localization.tracking, "Appearance") must have
# walked to where it is seen again at no more than this speed (m/s): a brisk walk, faster than
# people move indoors.
WALKING_SPEED = 2.0


def _positive(name: str, value: object) -> None:
    if not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
        raise InvalidInput(f"TrackerConfig.{name} must be a positive number, got {value!r}")


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of a `Tracker`.

    q: acceleration power spectral density, m^2 / s^3 (about the squared change of speed per
    second a target makes: people start, stop and turn). gate: squared Mahalanobis gate on the
    pixel innovation (chi-square, 2 dof). birth_gate: squared Mahalanobis distance on the floor
    within which a free detection is an existing track's outlier, not a new body;
    min_separation: metres, the same in plain distance. initial_speed_std: prior speed standard
    deviation per axis of a new track, m/s. Confirmation: a tentative track's score (module
    docstring) must reach confirm_score with at least confirm_hits updates within
    confirm_window (s) of its birth; below drop_score, or not updated for tentative_timeout (s),
    it is dropped (both stretched for a camera reporting slowly: module docstring). p_detect:
    probability that a camera detects a body it has in view; clutter_density: false detections
    per pixel per frame. ambiguity: a confirmed track's
    detection that another track explains within this many log-likelihood units counts as a
    sighting but does not update the state (crossing bodies coast through the crossing on
    their velocities; 0 turns it off), for at most ambiguity_coast seconds since the track's
    last update. coast_after, end_after (s): time without an update
    before a confirmed track coasts and ends; max_position_std (m): a coasting track whose
    position standard deviation (the larger axis) exceeds it ends (one with a look is lost
    instead: module docstring). camera_error_std (m): the
    error on the floor each detection inherits from its camera's calibration, added to its
    pixel covariance through the camera's floor Jacobian. A calibrated camera places points a
    centimetre or two from where another calibrated camera places them (the network
    calibration's bound within its frame, 1-2 cm and 0.1-0.4 deg per camera); without this
    term two cameras a few milliseconds apart, each sure of its pixel to 0.05 px, would make
    the filter explain their disagreement by a speed of metres per second. located_std (m): an
    unlabelled detection whose floor position has a standard deviation (larger axis) above it
    does not say where a body stands (a blob of two people, one behind the other; a head seen
    past a door jamb): such blobs also come with a biased bearing, so the tracker leaves them out
    (they neither update nor start a track; their track id is -1) and the tracks coast through
    them on their own velocities, as through a crossing (0: every detection counts). A "person"
    detection within body_radius of a robot's confirmed track is that robot's body (its marker
    missed by that camera) and is left out the same way.
    body_height, body_radius (m): the size of a body that can hide another from a camera; a
    tentative track hidden so (or inside the gate of a detection left out) is not missed.
    appearance_weight: cost units (-2 ln of a likelihood) a pairing pays per unit of
    appearance distance (core.localization.appearance, 0-1) between a detection's descriptor and
    the track's in the same camera; appearance_rate: the weight of each new descriptor in the
    track's running mean (module docstring, "Appearance"); recognition_distance: the largest
    appearance distance at which a newly confirmed track is a lost track's body.
    """

    q: float = 2.0
    gate: float = CHI2_2DOF_999
    birth_gate: float = CHI2_2DOF_999999
    min_separation: float = 0.45
    initial_speed_std: float = 1.0
    confirm_hits: int = 3
    confirm_score: float = 20.0
    drop_score: float = -6.0
    p_detect: float = 0.9
    clutter_density: float = 1e-5
    confirm_window: float = 1.0
    tentative_timeout: float = 0.4
    ambiguity: float = 3.0
    ambiguity_coast: float = 0.3
    coast_after: float = 0.5
    end_after: float = 5.0
    max_position_std: float = 2.0
    labelled_end_after: float = 60.0
    camera_error_std: float = 0.02
    located_std: float = 0.5
    body_height: float = 1.8
    body_radius: float = 0.25
    appearance_weight: float = 4.0
    appearance_rate: float = 0.2
    recognition_distance: float = 0.5

    def __post_init__(self) -> None:
        for name in (
            "q",
            "gate",
            "birth_gate",
            "initial_speed_std",
            "confirm_window",
            "tentative_timeout",
            "coast_after",
            "end_after",
            "max_position_std",
            "clutter_density",
            "ambiguity_coast",
            "labelled_end_after",
        ):
            _positive(name, getattr(self, name))
        for name in (
            "min_separation",
            "camera_error_std",
            "located_std",
            "body_height",
            "body_radius",
        ):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not (math.isfinite(value) and value >= 0):
                raise InvalidInput(f"TrackerConfig.{name} must be >= 0 metres, got {value!r}")
        w = self.appearance_weight
        if not isinstance(w, int | float) or not (math.isfinite(w) and w >= 0):
            raise InvalidInput(f"TrackerConfig.appearance_weight must be >= 0, got {w!r}")
        if not 0.0 <= self.recognition_distance <= 1.0:
            raise InvalidInput(
                "TrackerConfig.recognition_distance must lie in [0, 1], "
                f"got {self.recognition_distance!r}"
            )
        if not 0.0 < self.appearance_rate <= 1.0:
            raise InvalidInput(
                f"TrackerConfig.appearance_rate must lie in (0, 1], got {self.appearance_rate!r}"
            )
        if not 0.0 < self.p_detect < 1.0:
            raise InvalidInput(f"TrackerConfig.p_detect must lie in (0, 1), got {self.p_detect!r}")
        if not (math.isfinite(self.confirm_score) and math.isfinite(self.drop_score)) or not (
            self.drop_score < 0.0 < self.confirm_score
        ):
            raise InvalidInput(
                "TrackerConfig needs drop_score < 0 < confirm_score (log-likelihood ratios), "
                f"got {self.drop_score!r} and {self.confirm_score!r}"
            )
        if not isinstance(self.confirm_hits, int) or self.confirm_hits < 1:
            raise InvalidInput(
                f"TrackerConfig.confirm_hits must be an integer >= 1, got {self.confirm_hits!r}"
            )
        if self.end_after < self.coast_after:
            raise InvalidInput(
                f"end_after ({self.end_after} s) cannot be shorter than coast_after "
                f"({self.coast_after} s): a track would end before it coasts"
            )
