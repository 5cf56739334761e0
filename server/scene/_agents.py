"""What moves on the floor: robots and people as drawn markers, their tracks, camera images.

Parsing and checking happen here, in the caller's thread, so a bad value is refused at once with
InvalidInput and never reaches the drawing thread.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from server.scene._geometry import Pose

AGENT_KINDS = ("robot", "person")
# Sizes used when a caller leaves them out (m): a small home robot, an adult.
DEFAULT_SIZE = {"robot": (0.18, 0.30), "person": (0.22, 1.70)}
# A track keeps only its newest points: the scene shows where a target went recently, and a
# bounded message keeps a 10 Hz update cheap whatever the caller sends.
MAX_TRACK_POINTS = 600


@dataclass(frozen=True)
class AgentSpec:
    """A robot or a person on the floor: pose (m, rad about +Z, 0 = world +X) and size (m)."""

    id: str
    kind: str
    x: float
    y: float
    theta: float
    radius: float
    height: float

    @property
    def pose(self) -> Pose:
        """Return the agent's frame: at (x, y) on the floor, turned by theta about +Z."""
        half = 0.5 * self.theta
        return Pose(wxyz=(math.cos(half), 0.0, 0.0, math.sin(half)), position=(self.x, self.y, 0.0))


@dataclass(frozen=True)
class AgentView:
    """How one agent is drawn: scene node, pose, kind and size."""

    id: str
    kind: str
    node: str
    pose: Pose
    radius: float
    height: float


def agent_id(value: Any) -> str:
    """Return a non-empty agent or track id as a string; raise InvalidInput otherwise."""
    if not isinstance(value, str | int) or isinstance(value, bool) or str(value).strip() == "":
        raise InvalidInput(f"an agent id must be a non-empty string, got {value!r}")
    text = str(value).strip()
    if "/" in text:  # ids name scene nodes, where "/" separates parents from children
        raise InvalidInput(f"an agent id must not contain '/', got {text!r}")
    return text


def _finite(agent: Mapping[str, Any], key: str, default: float | None = None) -> float:
    value = agent.get(key, default)
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidInput(f"agent {key!r} must be a number, got {value!r}") from None
    if not math.isfinite(number):
        raise InvalidInput(f"agent {key!r} must be finite, got {number}")
    return number


def parse_agent(agent: Mapping[str, Any]) -> AgentSpec:
    """Return the checked agent {"id", "kind", "x", "y", "theta", "radius"?, "height"?}."""
    if not isinstance(agent, Mapping):
        raise InvalidInput(f"an agent must be a mapping, got {type(agent).__name__}")
    ident = agent_id(agent.get("id"))
    kind = agent.get("kind")
    if kind not in AGENT_KINDS:
        raise InvalidInput(f"agent {ident!r}: 'kind' must be one of {AGENT_KINDS}, got {kind!r}")
    radius0, height0 = DEFAULT_SIZE[kind]
    radius = _finite(agent, "radius", radius0)
    height = _finite(agent, "height", height0)
    if radius <= 0.0 or height <= 0.0:
        raise InvalidInput(
            f"agent {ident!r}: radius and height must be positive, got {radius}, {height}"
        )
    return AgentSpec(
        id=ident,
        kind=kind,
        x=_finite(agent, "x"),
        y=_finite(agent, "y"),
        theta=_finite(agent, "theta", 0.0),
        radius=radius,
        height=height,
    )


def parse_track(points: Sequence[Sequence[float]] | NDArray[np.float64]) -> NDArray[np.float64]:
    """Return a track's newest MAX_TRACK_POINTS points as an (N, 2) float array (N may be 0)."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"a track must be a list of [x, y] points: {exc}") from None
    if p.size == 0:
        return np.zeros((0, 2))
    if p.ndim != 2 or p.shape[1] != 2:
        raise InvalidInput(f"a track must be a list of [x, y] points, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InvalidInput("a track's points must be finite")
    return p[-MAX_TRACK_POINTS:].copy()


def check_image(image: Any) -> NDArray[np.uint8]:
    """Return a copy of a BGR (H, W, 3) or grey (H, W) uint8 image; raise InvalidInput if not."""
    if not isinstance(image, np.ndarray):
        raise InvalidInput(f"a camera image must be a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise InvalidInput(f"a camera image must be uint8, got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise InvalidInput(
            f"a camera image must be (H, W, 3) BGR or (H, W) grey, got shape {image.shape}"
        )
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise InvalidInput(f"a camera image must not be empty, got {image.shape}")
    return image.copy()


def display_image(image_bgr: NDArray[np.uint8], max_width: int) -> NDArray[np.uint8]:
    """Return the RGB image shown on a frustum: at most `max_width` wide (area averaging)."""
    import cv2

    img = image_bgr if image_bgr.ndim == 3 else cv2.cvtColor(image_bgr, cv2.COLOR_GRAY2BGR)
    h, w = img.shape[:2]
    if w > max_width:
        size = (max_width, max(1, round(h * max_width / w)))
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img[:, :, ::-1])


def parse_covariance(cov: Any) -> NDArray[np.float64]:
    """Return a 2x2 position covariance (m^2) as a symmetric array; raise InvalidInput unless
    it is finite, symmetric (to 1e-9 relative) and positive semi-definite."""
    try:
        c = np.asarray(cov, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"a covariance must be a 2x2 numeric matrix: {exc}") from None
    if c.shape != (2, 2) or not np.all(np.isfinite(c)):
        raise InvalidInput(f"a covariance must be a finite 2x2 matrix, got shape {c.shape}")
    scale = max(float(np.abs(c).max()), 1e-300)
    if abs(c[0, 1] - c[1, 0]) > 1e-9 * scale:
        raise InvalidInput(f"a covariance must be symmetric, got {c.tolist()}")
    c = 0.5 * (c + c.T)
    if np.linalg.eigvalsh(c)[0] < -1e-12 * scale:
        raise InvalidInput(f"a covariance must be positive semi-definite, got {c.tolist()}")
    return c


def ellipse_2sigma(cov: NDArray[np.float64]) -> tuple[float, float, float]:
    """Return the 2-sigma ellipse of a 2x2 covariance: semi-axes a >= b (m) and the angle of a
    from world +X (rad), from its eigen-decomposition (semi-axis = 2 sqrt(eigenvalue))."""
    w, v = np.linalg.eigh(cov)
    w = np.clip(w, 0.0, None)
    return (
        2.0 * math.sqrt(w[1]),
        2.0 * math.sqrt(w[0]),
        math.atan2(float(v[1, 1]), float(v[0, 1])),
    )
