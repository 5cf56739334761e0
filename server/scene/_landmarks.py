"""Landmarks and the maps they build, in the live scene (spec 04): every placed landmark as a
labelled frame, the semantic map's objects, and the navigation graph (places as points, edges
as lines).

* a landmark is drawn at its pose T_world_landmark (mark frame: x along the print's rows, z out
  of the printed face): its axes, a thin plate of its printed size in its kind's colour (blue
  frame of an object mark, red rings of a signpost, grey otherwise) and its name;
* a semantic object is a small sphere at its mark's fused world position, labelled with its
  name and class;
* the navigation graph lies just above the floor: one point per place at its (x, y), labelled
  with its name, and one line per edge.

Each of the three is replaced as a whole (they hold tens of items and change when a survey
reads a mark, not at frame rate). `LandmarkLayer` is the part of SceneService that holds and
draws them; it uses the service's lock (`_cond`) and viser server (`_server`).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from core.errors import InvalidInput
from server.scene._entries import LandmarkEntry, PlaceEntry, SemanticObjectEntry
from server.scene._geometry import Pose, pose_from_transform

T = TypeVar("T")

# The printed patterns' colours (spec 04: pure blue frames, pure red rings).
_COLOR_KIND = {"object": (0, 0, 255), "signpost": (255, 0, 0)}
_COLOR_OTHER = (100, 116, 139)
_COLOR_OBJECT = (13, 148, 136)
_COLOR_PLACE = (202, 138, 4)
_COLOR_EDGE = (161, 98, 7)
# The navigation graph floats this far (m) above the floor: over the room fills and the
# tracks, under the planned path.
_GRAPH_HEIGHT = 0.014
# A landmark's axes are at least this long (m), so a 10 cm mark's frame stays visible.
_MIN_AXES = 0.12
# Beyond this many items a map is a mistake (a home has tens).
MAX_ITEMS = 10_000


@dataclass(frozen=True)
class LandmarkView:
    """One landmark as drawn: its id, name, kind ("object", "signpost" or another registry
    kind), printed size (m), scene node and pose (T_world_landmark)."""

    id: str
    name: str
    kind: str
    size: float
    node: str
    pose: Pose


@dataclass(frozen=True)
class SemanticObjectView:
    """One object of the semantic map as drawn: its key (scene id), name, class, room, node and
    its mark's world pose."""

    id: str
    name: str
    object_class: str
    room: str
    node: str
    pose: Pose


@dataclass(frozen=True)
class PlaceView:
    """One place of the navigation graph: its key, name, room and floor position (x, y) m."""

    id: str
    name: str
    room: str
    xy: tuple[float, float]


@dataclass(frozen=True)
class NavigationGraphView:
    """The navigation graph as drawn: its places by key and its edges (pairs of keys)."""

    places: dict[str, PlaceView]
    edges: tuple[tuple[str, str], ...]


def _key(value: Any, what: str) -> str:
    """Return a non-empty id as a string (it names a scene node, so no '/')."""
    if not isinstance(value, str | int) or isinstance(value, bool) or str(value).strip() == "":
        raise InvalidInput(f"{what}: an id must be a non-empty string or integer, got {value!r}")
    text = str(value).strip()
    if "/" in text:
        raise InvalidInput(f"{what}: an id must not contain '/', got {text!r}")
    return text


def _items(values: Sequence[T], what: str) -> Sequence[T]:
    if len(values) > MAX_ITEMS:
        raise InvalidInput(f"{what} hold at most {MAX_ITEMS} items, got {len(values)}")
    return values


def _unique(ids: list[str], what: str) -> None:
    seen: set[str] = set()
    for ident in ids:
        if ident in seen:
            raise InvalidInput(f"{what}: id {ident!r} appears twice")
        seen.add(ident)


def parse_landmarks(landmarks: Sequence[LandmarkEntry]) -> tuple[LandmarkView, ...]:
    """Return the checked landmarks (T_world_landmark 4x4 rigid, size in (0, 10] m); raise
    InvalidInput naming what is wrong."""
    out = []
    for item in _items(landmarks, "landmarks"):
        ident = _key(item.id, "landmarks")
        pose = pose_from_transform(item.T_world_landmark, f"landmark {ident} pose")
        size = float(item.size)
        if not (math.isfinite(size) and 0.0 < size <= 10.0):
            raise InvalidInput(f"landmark {ident}: 'size' must lie in (0, 10] m, got {size}")
        out.append(
            LandmarkView(
                id=ident,
                name=item.name or f"landmark {ident}",
                kind=item.kind or "landmark",
                size=size,
                node=f"/landmarks/{ident}",
                pose=pose,
            )
        )
    _unique([v.id for v in out], "landmarks")
    return tuple(out)


def parse_semantic_objects(
    objects: Sequence[SemanticObjectEntry],
) -> tuple[SemanticObjectView, ...]:
    """Return the checked semantic objects (T_world_mark 4x4 rigid); raise InvalidInput naming
    what is wrong."""
    out = []
    for item in _items(objects, "semantic objects"):
        ident = _key(item.id, "semantic objects")
        pose = pose_from_transform(item.T_world_mark, f"semantic object {ident} pose")
        out.append(
            SemanticObjectView(
                id=ident,
                name=item.name or f"object {ident}",
                object_class=item.object_class,
                room=item.room,
                node=f"/maps/semantic/{ident}",
                pose=pose,
            )
        )
    _unique([v.id for v in out], "semantic objects")
    return tuple(out)


def parse_navigation_graph(
    places: Sequence[PlaceEntry], edges: Sequence[Sequence[str]]
) -> NavigationGraphView:
    """Return the checked navigation graph: places (position [x, y] or [x, y, z] m) and edges
    [[id, id], ...] between listed places; raise InvalidInput naming what is wrong (an edge to
    an unknown place, a loop, a bad position)."""
    parsed: dict[str, PlaceView] = {}
    for item in _items(places, "navigation places"):
        ident = _key(item.id, "navigation places")
        if ident in parsed:
            raise InvalidInput(f"navigation places: id {ident!r} appears twice")
        position = item.position
        try:
            p = np.asarray(position, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidInput(
                f"place {ident}: 'position' must be [x, y] or [x, y, z] m, got {position!r}"
            ) from None
        if p.shape not in ((2,), (3,)) or not np.all(np.isfinite(p)):
            raise InvalidInput(
                f"place {ident}: 'position' must be a finite [x, y] or [x, y, z], got {position!r}"
            )
        parsed[ident] = PlaceView(
            id=ident,
            name=item.name or f"place {ident}",
            room=item.room,
            xy=(float(p[0]), float(p[1])),
        )
    if not isinstance(edges, Sequence) or isinstance(edges, str | bytes):
        raise InvalidInput(f"navigation edges must be a list of [id, id], got {edges!r}")
    pairs = []
    for i, edge in enumerate(edges):
        if not isinstance(edge, Sequence) or isinstance(edge, str | bytes) or len(edge) != 2:
            raise InvalidInput(f"navigation edge {i} must be [id, id], got {edge!r}")
        a, b = _key(edge[0], f"navigation edge {i}"), _key(edge[1], f"navigation edge {i}")
        for end in (a, b):
            if end not in parsed:
                raise InvalidInput(f"navigation edge {i} names place {end!r}, which is not listed")
        if a == b:
            raise InvalidInput(f"navigation edge {i} joins place {a!r} to itself")
        pairs.append((a, b) if a <= b else (b, a))
    return NavigationGraphView(places=parsed, edges=tuple(dict.fromkeys(pairs)))


class LandmarkLayer:
    """The landmarks and maps of SceneService: thread-safe state changes, drawing on the
    scene's worker."""

    _cond: threading.Condition
    _server: Any

    def _init_landmarks(self) -> None:
        self._landmark_specs: tuple[LandmarkView, ...] = ()
        self._object_specs: tuple[SemanticObjectView, ...] = ()
        self._graph_spec = NavigationGraphView({}, ())
        self._dirty_maps: set[str] = set()  # "landmarks", "semantic", "navigation"
        self._drawn_landmarks: dict[str, LandmarkView] = {}
        self._drawn_objects: dict[str, SemanticObjectView] = {}
        self._drawn_graph = NavigationGraphView({}, ())

    def _restart_landmarks(self) -> None:
        """Under _cond, when the server (re)starts: everything is to be drawn again."""
        self._dirty_maps = {"landmarks", "semantic", "navigation"}
        self._drawn_landmarks = {}
        self._drawn_objects = {}
        self._drawn_graph = NavigationGraphView({}, ())

    def _landmarks_dirty(self) -> bool:
        return bool(self._dirty_maps)

    def _take_landmarks(
        self,
    ) -> tuple[
        set[str],
        tuple[LandmarkView, ...],
        tuple[SemanticObjectView, ...],
        NavigationGraphView,
    ]:
        """Under _cond: which of the three changed since the last call, and their state."""
        dirty, self._dirty_maps = self._dirty_maps, set()
        return dirty, self._landmark_specs, self._object_specs, self._graph_spec

    # -- state changes (any thread) ----------------------------------------------------------

    def set_landmarks(self, landmarks: Sequence[LandmarkEntry]) -> None:
        """Replace the landmarks shown by `landmarks` (size: the printed pattern's side or ring
        diameter, m; T_world_landmark: 4x4 rigid, the mark frame, z out of the printed face); an
        empty list removes them. Raises InvalidInput (nothing changes) for a malformed item."""
        parsed = parse_landmarks(landmarks)
        with self._cond:
            self._landmark_specs = parsed
            self._dirty_maps.add("landmarks")
            self._cond.notify_all()

    def set_semantic_objects(self, objects: Sequence[SemanticObjectEntry]) -> None:
        """Replace the semantic map shown by `objects` (T_world_mark 4x4 rigid); an empty list
        removes it. Raises InvalidInput (nothing changes) for a malformed item."""
        parsed = parse_semantic_objects(objects)
        with self._cond:
            self._object_specs = parsed
            self._dirty_maps.add("semantic")
            self._cond.notify_all()

    def set_navigation_graph(
        self, places: Sequence[PlaceEntry], edges: Sequence[Sequence[str]]
    ) -> None:
        """Replace the navigation graph shown: places (position [x, y] or [x, y, z] m; drawn on
        the floor at x, y) and edges [[id, id], ...]; empty lists remove it. Raises
        InvalidInput (nothing changes) for a malformed place or an edge to an unknown place."""
        parsed = parse_navigation_graph(places, edges)
        with self._cond:
            self._graph_spec = parsed
            self._dirty_maps.add("navigation")
            self._cond.notify_all()

    def landmarks(self) -> dict[str, LandmarkView]:
        """Return the landmarks as currently drawn, by id."""
        with self._cond:
            return dict(self._drawn_landmarks)

    def semantic_objects(self) -> dict[str, SemanticObjectView]:
        """Return the semantic map's objects as currently drawn, by id."""
        with self._cond:
            return dict(self._drawn_objects)

    def navigation_graph(self) -> NavigationGraphView:
        """Return the navigation graph as currently drawn."""
        with self._cond:
            return self._drawn_graph

    # -- drawing (worker thread) -------------------------------------------------------------

    def _draw_landmark_layers(
        self,
        dirty: set[str],
        landmarks: tuple[LandmarkView, ...],
        objects: tuple[SemanticObjectView, ...],
        graph: NavigationGraphView,
    ) -> None:
        server = self._server
        if server is None or not dirty:
            return
        with server.atomic():
            if "landmarks" in dirty:
                server.scene.remove_by_name("/landmarks")
                for lm in landmarks:
                    self._draw_landmark(server, lm)
            if "semantic" in dirty:
                server.scene.remove_by_name("/maps/semantic")
                for obj in objects:
                    self._draw_object(server, obj)
            if "navigation" in dirty:
                self._draw_graph(server, graph)
        with self._cond:
            if "landmarks" in dirty:
                self._drawn_landmarks = {v.id: v for v in landmarks}
            if "semantic" in dirty:
                self._drawn_objects = {v.id: v for v in objects}
            if "navigation" in dirty:
                self._drawn_graph = graph

    @staticmethod
    def _draw_landmark(server: Any, lm: LandmarkView) -> None:
        axes = max(0.6 * lm.size, _MIN_AXES)
        server.scene.add_frame(
            lm.node,
            wxyz=lm.pose.wxyz,
            position=lm.pose.position,
            axes_length=axes,
            axes_radius=0.06 * axes,
        )
        # The print, a thin plate just behind the frame's origin (the face looks along +z).
        server.scene.add_box(
            f"{lm.node}/plate",
            color=_COLOR_KIND.get(lm.kind, _COLOR_OTHER),
            dimensions=(lm.size, lm.size, 0.004),
            position=(0.0, 0.0, -0.002),
            cast_shadow=False,
            receive_shadow=False,
        )
        server.scene.add_label(
            f"{lm.node}/label",
            lm.name,
            position=(0.0, -0.6 * lm.size, 0.02),
            anchor="top-center",
            font_screen_scale=0.75,
        )

    @staticmethod
    def _draw_object(server: Any, obj: SemanticObjectView) -> None:
        server.scene.add_icosphere(
            obj.node,
            radius=0.05,
            color=_COLOR_OBJECT,
            subdivisions=2,
            wxyz=obj.pose.wxyz,
            position=obj.pose.position,
        )
        text = f"{obj.name} ({obj.object_class})" if obj.object_class else obj.name
        server.scene.add_label(
            f"{obj.node}/label",
            text,
            position=(0.0, 0.0, 0.0),
            anchor="bottom-center",
            font_screen_scale=0.75,
        )

    @staticmethod
    def _draw_graph(server: Any, graph: NavigationGraphView) -> None:
        server.scene.remove_by_name("/maps/navigation")
        if not graph.places:
            return
        keys = list(graph.places)
        xy = np.array([graph.places[k].xy for k in keys], dtype=np.float64)
        points = np.column_stack([xy, np.full(len(xy), _GRAPH_HEIGHT)])
        server.scene.add_point_cloud(
            "/maps/navigation/places",
            points=points,
            colors=_COLOR_PLACE,
            point_size=0.12,
            point_shape="circle",
            precision="float32",
        )
        for key, p in zip(keys, points, strict=True):
            server.scene.add_label(
                f"/maps/navigation/labels/{key}",
                graph.places[key].name,
                position=(float(p[0]), float(p[1]), 0.05),
                anchor="bottom-center",
                font_screen_scale=0.7,
            )
        if graph.edges:
            index = {k: i for i, k in enumerate(keys)}
            ends = np.array([[index[a], index[b]] for a, b in graph.edges])
            server.scene.add_line_segments(
                "/maps/navigation/edges",
                points=points[ends],  # (E, 2, 3)
                colors=_COLOR_EDGE,
                thickness=3.0,
                thickness_units="screen",
            )
