"""QR-code landmarks: payload, printable artwork, detection, location, reading and the maps.

* `core.landmarks.payload`: the versioned text schema (`encode_payload`, `decode_payload`).
* `core.landmarks.artwork`: SVG, PDF and PNG at true size (`make_artwork`, `to_svg`, ...).
* `core.landmarks.detect`: `detect_landmarks(image, K, dist)`, made of one private module per
  part (the lens maps, edges, frames, rings, the rings' pose, the symbol; its docstring lists them).
* `core.landmarks.conics`: ellipse fits and the circle geometry the rings use.
* `core.landmarks.ambiguity`: the two poses of a signpost's rings, their probabilities, the
  decision and their fusion over views (`PoseHypothesis`, `fuse_hypotheses`).
* `core.landmarks.maps`: the semantic map (objects) and the navigation map (places, routes).
"""

from core.landmarks.ambiguity import DECIDED_PROBABILITY, PoseHypothesis, fuse_hypotheses
from core.landmarks.detect import LandmarkDetection, detect_landmarks
from core.landmarks.maps import (
    NavigationMap,
    NoRoute,
    Route,
    SemanticMap,
    detection_in_world,
    hypotheses_in_world,
)
from core.landmarks.payload import (
    ObjectMark,
    PayloadError,
    Record,
    Signpost,
    decode_payload,
    encode_payload,
)

__all__ = [
    "DECIDED_PROBABILITY",
    "LandmarkDetection",
    "NavigationMap",
    "NoRoute",
    "ObjectMark",
    "PayloadError",
    "PoseHypothesis",
    "Record",
    "Route",
    "SemanticMap",
    "Signpost",
    "decode_payload",
    "detect_landmarks",
    "detection_in_world",
    "encode_payload",
    "fuse_hypotheses",
    "hypotheses_in_world",
]
