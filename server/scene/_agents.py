"""What moves on the floor: robots and people as drawn markers, and their tracks with the
2-sigma ellipse of their newest point.

Parsing and checking happen in the caller's thread, so a bad value is refused at once with
InvalidInput and never reaches the drawing thread. `AgentLayer` is the part of SceneService
that holds and draws agents and tracks; it uses the service's lock (`_cond`) and viser server
(`_server`).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from server.scene._geometry import Pose, as_xy_points

AGENT_KINDS = ("robot", "person")
# Sizes used when a caller leaves them out (m): a small home robot, an adult.
DEFAULT_SIZE = {"robot": (0.18, 0.30), "person": (0.22, 1.70)}
# A track keeps only its newest points: the scene shows where a target went recently, and a
# bounded message keeps a 10 Hz update cheap whatever the caller sends.
MAX_TRACK_POINTS = 600
# Robots in orange, people in violet (the dashboard's floor page uses the same two colours).
_COLOR_ROBOT = (234, 88, 12)
_COLOR_PERSON = (124, 58, 237)
_COLOR_HEADING = (255, 255, 255)
_COLOR_TRACK = {"robot": (194, 65, 12), "person": (109, 40, 217)}
_COLOR_TRACK_UNKNOWN = (71, 85, 105)
# Tracks float this far (m) above the floor, so the room fills never hide them.
_TRACK_HEIGHT = 0.012


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
    p = as_xy_points(points, "a track")
    if not np.all(np.isfinite(p)):
        raise InvalidInput("a track's points must be finite")
    return p[-MAX_TRACK_POINTS:].copy()


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


class AgentLayer:
    """The robots, people and tracks of SceneService: thread-safe state changes, drawing on the
    scene's worker."""

    _cond: threading.Condition
    _server: Any

    def _init_agents(self) -> None:
        self._agents: dict[str, AgentSpec] = {}
        self._tracks: dict[str, np.ndarray] = {}
        self._track_covs: dict[str, np.ndarray] = {}  # covariance of a track's newest point
        self._dirty_agents: set[str] = set()
        self._dirty_tracks: set[str] = set()
        # What the worker has drawn; read by agents() / tracks() under _cond.
        self._drawn_agents: dict[str, AgentView] = {}
        self._drawn_tracks: dict[str, np.ndarray] = {}

    def _restart_agents(self) -> None:
        """Under _cond, when the server (re)starts: everything is to be drawn again."""
        self._dirty_agents = set(self._agents)
        self._dirty_tracks = set(self._tracks)
        self._drawn_agents = {}
        self._drawn_tracks = {}

    def _agents_dirty(self) -> bool:
        return bool(self._dirty_agents or self._dirty_tracks)

    def _take_agents(
        self,
    ) -> tuple[dict[str, AgentSpec | None], dict[str, tuple[np.ndarray | None, np.ndarray | None]]]:
        """Under _cond: the agents changed since the last call (None: removed) and the tracks
        changed (points and newest covariance; None: removed)."""
        moved = {i: self._agents.get(i) for i in self._dirty_agents}
        tracks = {i: (self._tracks.get(i), self._track_covs.get(i)) for i in self._dirty_tracks}
        self._dirty_agents, self._dirty_tracks = set(), set()
        return moved, tracks

    # -- state changes (any thread) ----------------------------------------------------------

    def upsert_agent(self, agent: Mapping[str, Any]) -> None:
        """Add or move a robot or a person: {"id", "kind": "robot" | "person", "x", "y",
        "theta", "radius", "height"} (m, rad about +Z from world +X; radius and height default
        by kind). A robot is a cylinder with a heading bar, a person a body with a head.

        Moving an agent only moves its frame; the meshes are rebuilt when its kind or size
        changes. Raises InvalidInput (nothing changes) for a bad id, kind or number.
        """
        spec = parse_agent(agent)
        with self._cond:
            self._agents[spec.id] = spec
            self._dirty_agents.add(spec.id)
            self._cond.notify_all()

    def remove_agent(self, id: str) -> None:
        """Remove an agent and its track (nothing happens if it is not there)."""
        ident = agent_id(id)
        with self._cond:
            self._agents.pop(ident, None)
            self._tracks.pop(ident, None)
            self._track_covs.pop(ident, None)
            self._dirty_agents.add(ident)
            self._dirty_tracks.add(ident)
            self._cond.notify_all()

    def clear_agents(self) -> None:
        """Remove every agent and every track (the space shown changed: they were its)."""
        with self._cond:
            gone = set(self._agents) | set(self._tracks)
            self._agents.clear()
            self._tracks.clear()
            self._track_covs.clear()
            self._dirty_agents |= gone
            self._dirty_tracks |= gone
            self._cond.notify_all()

    def set_track(
        self,
        id: str,
        points: Sequence[Sequence[float]],
        cov: Sequence[Sequence[float]] | None = None,
    ) -> None:
        """Replace a target's track by the poly-line through `points` ([[x, y], ...], m), drawn
        just above the floor; only the newest MAX_TRACK_POINTS are kept, and an empty list
        removes the track. `cov`, the 2x2 covariance (m^2) of the newest point, is drawn as its
        2-sigma ellipse there (a flat translucent disc, true size). Raises InvalidInput
        (nothing changes) for malformed points or a covariance that is not one."""
        ident = agent_id(id)
        track = parse_track(points)
        covariance = None if cov is None else parse_covariance(cov)
        with self._cond:
            if len(track):
                self._tracks[ident] = track
            else:
                self._tracks.pop(ident, None)
            if covariance is not None and len(track):
                self._track_covs[ident] = covariance
            else:
                self._track_covs.pop(ident, None)
            self._dirty_tracks.add(ident)
            self._cond.notify_all()

    # -- what is drawn -----------------------------------------------------------------------

    def agents(self) -> dict[str, AgentView]:
        """Return the robots and people as currently drawn, by id."""
        with self._cond:
            return dict(self._drawn_agents)

    def tracks(self) -> dict[str, np.ndarray]:
        """Return the tracks as currently drawn: id -> (N, 2) points (m)."""
        with self._cond:
            return {k: v.copy() for k, v in self._drawn_tracks.items()}

    # -- drawing (worker thread) -------------------------------------------------------------

    def _draw_agents(self, moved: dict[str, AgentSpec | None]) -> None:
        server = self._server
        if server is None or not moved:
            return
        drawn = dict(self._drawn_agents)
        with server.atomic():
            for ident, spec in sorted(moved.items()):
                node = f"/agents/{ident}"
                old = drawn.get(ident)
                if spec is None:
                    server.scene.remove_by_name(node)
                    drawn.pop(ident, None)
                    continue
                pose = spec.pose
                frame = server.scene.get_handle_by_name(node)
                if (
                    old is not None
                    and frame is not None
                    and old.kind == spec.kind
                    and (
                        old.radius,
                        old.height,
                    )
                    == (spec.radius, spec.height)
                ):
                    frame.position = pose.position  # a move: one small message, no meshes
                    frame.wxyz = pose.wxyz
                else:
                    server.scene.remove_by_name(node)
                    self._draw_agent(server, spec, node)
                drawn[ident] = AgentView(
                    id=spec.id,
                    kind=spec.kind,
                    node=node,
                    pose=pose,
                    radius=spec.radius,
                    height=spec.height,
                )
        with self._cond:
            self._drawn_agents = drawn

    @staticmethod
    def _draw_agent(server: Any, spec: AgentSpec, node: str) -> None:
        pose = spec.pose
        server.scene.add_frame(node, wxyz=pose.wxyz, position=pose.position, show_axes=False)
        r, h = spec.radius, spec.height
        if spec.kind == "robot":
            # Cylinders in viser stand along +Z, centred on their position.
            server.scene.add_cylinder(
                f"{node}/body", radius=r, height=h, color=_COLOR_ROBOT, position=(0.0, 0.0, h / 2)
            )
            # The heading: a bar from the centre to the front rim (agent +X) on the top face.
            server.scene.add_box(
                f"{node}/heading",
                color=_COLOR_HEADING,
                dimensions=(r, 0.25 * r, 0.02),
                position=(r / 2, 0.0, h + 0.01),
            )
        else:
            head = min(0.12, 0.4 * r, 0.1 * h)
            body = max(h - 2.0 * head, 0.01)
            server.scene.add_cylinder(
                f"{node}/body",
                radius=r,
                height=body,
                color=_COLOR_PERSON,
                position=(0.0, 0.0, body / 2),
            )
            server.scene.add_icosphere(
                f"{node}/head", radius=head, color=_COLOR_PERSON, position=(0.0, 0.0, h - head)
            )
        server.scene.add_label(
            f"{node}/label",
            spec.id,
            position=(0.0, 0.0, h + 0.15),
            anchor="bottom-center",
            font_screen_scale=0.8,
        )

    def _draw_tracks(self, tracks: dict[str, tuple[np.ndarray | None, np.ndarray | None]]) -> None:
        server = self._server
        if server is None or not tracks:
            return
        drawn = dict(self._drawn_tracks)
        with self._cond:
            kinds = {i: a.kind for i, a in self._agents.items()}
        with server.atomic():
            for ident, (points, cov) in sorted(tracks.items()):
                node = f"/tracks/{ident}"
                colour = _COLOR_TRACK.get(kinds.get(ident, ""), _COLOR_TRACK_UNKNOWN)
                self._draw_uncertainty(server, ident, points, cov, colour)
                if points is None or len(points) < 2:
                    server.scene.remove_by_name(node)
                    if points is None:
                        drawn.pop(ident, None)
                    else:
                        drawn[ident] = points
                    continue
                segments = np.stack([points[:-1], points[1:]], axis=1)  # (N - 1, 2, 2)
                height = np.full((len(segments), 2, 1), _TRACK_HEIGHT)
                server.scene.add_line_segments(
                    node,
                    points=np.concatenate([segments, height], axis=2),
                    colors=colour,
                    thickness=2.5,
                    thickness_units="screen",
                )
                drawn[ident] = points
        with self._cond:
            self._drawn_tracks = drawn

    @staticmethod
    def _draw_uncertainty(
        server: Any,
        ident: str,
        points: np.ndarray | None,
        cov: np.ndarray | None,
        colour: tuple[int, int, int],
    ) -> None:
        """Draw the 2-sigma ellipse of a track's newest point: a unit disc scaled to the
        semi-axes and turned to the major axis (viser cylinders stand along +Z)."""
        node = f"/uncertainty/{ident}"
        if points is None or not len(points) or cov is None:
            server.scene.remove_by_name(node)
            return
        a, b, angle = ellipse_2sigma(cov)
        x, y = (float(v) for v in points[-1])
        server.scene.add_cylinder(
            node,
            radius=1.0,
            height=0.004,
            color=colour,
            opacity=0.35,
            scale=(max(a, 1e-5), max(b, 1e-5), 1.0),  # a zero scale breaks the mesh normals
            wxyz=(math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)),
            position=(x, y, _TRACK_HEIGHT / 2),
            cast_shadow=False,
            receive_shadow=False,
        )
