"""The maps landmarks build: the global semantic map (objects) and the navigation map (places).

* `SemanticMap`: one entry per object-mark id: class, name, room, world pose, its covariance,
  last seen, times read, confidence. Reading a mark again fuses the new pose into the entry
  (information-weighted mean of the positions, covariance-weighted mean of the rotations on the
  tangent space) and never adds a second entry. confidence = 1 - 2^-n for n reads (a single read
  is a hypothesis; three agree-ing reads make it 0.875).
* `NavigationMap`: signposts as places (nodes, at the pose their payload carries), edges from
  their neighbour fields (an edge exists once both ends have been read) and from the floor plan
  (places in one room are connected), weighted by the straight-line distance; shortest routes
  between rooms by Dijkstra (networkx).

Both give JSON-ready dictionaries with GeoJSON-like features (x, y on the floor plan, metres).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations
from typing import Any

import networkx as nx
import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix
from core.errors import IntspaceError, InvalidInput
from core.geometry.camera import left_jacobian_so3
from core.geometry.rotations import matrix_to_rotvec, nearest_rotation, rotvec_to_matrix
from core.landmarks.ambiguity import PoseHypothesis
from core.landmarks.detect import LandmarkDetection
from core.landmarks.payload import ObjectMark, Signpost

Array = NDArray[np.float64]


class NoRoute(IntspaceError):
    """No route joins the two rooms in the navigation map (or a room has no place yet)."""


def _pose_matrix(T: ArrayLike, name: str) -> Array:
    M = as_matrix(T, (4, 4), name)
    R = M[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise InvalidInput(f"{name} must be a rigid transform (its rotation part orthonormal)")
    return M


def _cov6(cov: ArrayLike, name: str) -> Array:
    C = as_matrix(cov, (6, 6), name)
    C = (C + C.T) / 2
    if np.min(np.linalg.eigvalsh(C)) <= 0:
        raise InvalidInput(f"{name} must be a positive definite 6x6 covariance")
    return C


def _in_world(T_cam_mark: Array, cov: Array, Twc: Array) -> tuple[Array, Array]:
    T = Twc @ T_cam_mark
    Jl = left_jacobian_so3(matrix_to_rotvec(T_cam_mark[:3, :3]))
    M = np.zeros((6, 6))
    M[:3, :3] = Twc[:3, :3] @ Jl
    M[3:, 3:] = Twc[:3, :3]
    return T, M @ cov @ M.T


def detection_in_world(det: LandmarkDetection, T_world_cam: ArrayLike) -> tuple[Array, Array]:
    """Return (T_world_mark (4, 4), its (6, 6) covariance of (left rotation perturbation in the
    world frame, position in the world)) of a detection seen by a camera at T_world_cam (held
    exact). The detection's covariance is of (rvec, t) in the camera frame (for a signpost
    whose image cannot decide its pose, the covariance covering both of its poses)."""
    Twc = _pose_matrix(T_world_cam, "T_world_cam")
    return _in_world(det.T_cam_mark, det.cov, Twc)


def hypotheses_in_world(
    det: LandmarkDetection, T_world_cam: ArrayLike
) -> tuple[PoseHypothesis, ...]:
    """Return a detection's pose hypotheses in the world frame of a camera at T_world_cam (held
    exact), best first: each T_world_mark (4, 4), its own (6, 6) covariance of (left rotation
    perturbation in the world, position) and its probability given the image; one hypothesis
    (probability 1) for a detection without alternatives (a frame). What
    core.landmarks.ambiguity.fuse_hypotheses fuses over views."""
    Twc = _pose_matrix(T_world_cam, "T_world_cam")
    if not det.hypotheses:
        return (PoseHypothesis(*_in_world(det.T_cam_mark, det.cov, Twc), 1.0),)
    return tuple(PoseHypothesis(*_in_world(h.T, h.cov, Twc), h.probability) for h in det.hypotheses)


@dataclass
class SemanticObject:
    """One object in the semantic map (see the module docstring); T_world_mark (4, 4),
    cov (6, 6) of (rotation perturbation, position) in the world, metres and radians."""

    id: int
    object_class: str
    name: str
    room: str
    T_world_mark: Array = field(repr=False)
    cov: Array = field(repr=False)
    last_seen: float
    reads: int
    record: ObjectMark = field(repr=False)

    @property
    def position(self) -> Array:
        """Return the mark's position (3,) in the world, metres."""
        return self.T_world_mark[:3, 3]

    @property
    def confidence(self) -> float:
        """Return 1 - 2^-reads."""
        return 1.0 - 0.5**self.reads

    def to_feature(self) -> dict[str, Any]:
        """Return the object as a GeoJSON-like Point feature (x, y metres) with its fields."""
        p = self.position
        return {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [float(p[0]), float(p[1])]},
            "properties": {
                "id": self.id,
                "class": self.object_class,
                "name": self.name,
                "room": self.room,
                "z": float(p[2]),
                "T_world_mark": self.T_world_mark.tolist(),
                "position_sd_m": np.sqrt(np.diag(self.cov)[3:]).tolist(),
                "last_seen": self.last_seen,
                "reads": self.reads,
                "confidence": self.confidence,
            },
        }


class SemanticMap:
    """The global semantic map: objects keyed by their mark's id (module docstring)."""

    def __init__(self) -> None:
        self._objects: dict[int, SemanticObject] = {}

    def __len__(self) -> int:
        return len(self._objects)

    def __getitem__(self, ident: int) -> SemanticObject:
        return self._objects[ident]

    @property
    def objects(self) -> list[SemanticObject]:
        """Return the objects, by id."""
        return [self._objects[k] for k in sorted(self._objects)]

    def observe(
        self, record: ObjectMark, T_world_mark: ArrayLike, cov: ArrayLike, time: float
    ) -> SemanticObject:
        """Return the object after a read of its mark: a new entry, or the existing one with
        the pose fused and the payload's fields (class, name, room) updated.

        record: the decoded ObjectMark (a Signpost belongs to the navigation map: InvalidInput);
        T_world_mark (4, 4); cov (6, 6) of (rotation perturbation, position) in the world.
        """
        if not isinstance(record, ObjectMark):
            raise InvalidInput(
                f"the semantic map takes object marks; {type(record).__name__} records go to "
                "the navigation map"
            )
        T = _pose_matrix(T_world_mark, "T_world_mark")
        C = _cov6(cov, "cov")
        if not np.isfinite(time):
            raise InvalidInput(f"time must be finite, got {time}")
        old = self._objects.get(record.id)
        if old is None:
            obj = SemanticObject(
                record.id, record.object_class, record.name, record.room, T, C, time, 1, record
            )
        else:
            Tf, Cf = _fuse(old.T_world_mark, old.cov, T, C)
            obj = SemanticObject(
                record.id,
                record.object_class,
                record.name,
                record.room,
                Tf,
                Cf,
                max(old.last_seen, time),
                old.reads + 1,
                record,
            )
        self._objects[record.id] = obj
        return obj

    def to_dict(self) -> dict[str, Any]:
        """Return the map as a GeoJSON-like FeatureCollection."""
        return {"type": "FeatureCollection", "features": [o.to_feature() for o in self.objects]}


def _fuse(T1: Array, C1: Array, T2: Array, C2: Array) -> tuple[Array, Array]:
    """Return the information-weighted fusion of two pose estimates (rotation on the tangent
    space at T1: R = exp(d) R1 with d the weighted mean of 0 and log(R2 R1^T))."""
    I1 = np.linalg.inv(C1)
    I2 = np.linalg.inv(C2)
    Cf = np.linalg.inv(I1 + I2)
    d2 = np.concatenate([matrix_to_rotvec(T2[:3, :3] @ T1[:3, :3].T), T2[:3, 3] - T1[:3, 3]])
    delta = Cf @ (I2 @ d2)
    T = np.eye(4)
    T[:3, :3] = nearest_rotation(rotvec_to_matrix(delta[:3]) @ T1[:3, :3])
    T[:3, 3] = T1[:3, 3] + delta[3:]
    return T, Cf


@dataclass(frozen=True)
class Route:
    """A shortest route: the places' ids in order, their rooms, and its length in metres."""

    places: tuple[int, ...]
    rooms: tuple[str, ...]
    length_m: float


class NavigationMap:
    """The local navigation map: signposts as places, edges from neighbour fields and rooms."""

    def __init__(self) -> None:
        self._graph: nx.Graph = nx.Graph()
        self._records: dict[int, Signpost] = {}

    def __len__(self) -> int:
        return len(self._records)

    @property
    def graph(self) -> nx.Graph:
        """Return a copy of the graph (nodes: place ids with name, room, position)."""
        return self._graph.copy()

    @property
    def rooms(self) -> list[str]:
        """Return the rooms with at least one place, sorted."""
        return sorted({r.room for r in self._records.values()})

    def observe(self, record: Signpost) -> bool:
        """Add or update the place of a read signpost; return True when it was new.

        Its position is the world pose its payload carries; its edges are its neighbours that
        are already places (the others join when they are read) and the other places of its
        room (the floor plan: one room is free space).
        """
        if not isinstance(record, Signpost):
            raise InvalidInput(
                f"the navigation map takes signposts; {type(record).__name__} records go to "
                "the semantic map"
            )
        new = record.id not in self._records
        if not new:
            self._graph.remove_node(record.id)
        self._records[record.id] = record
        self._graph.add_node(record.id, name=record.name, room=record.room, xyz=record.pose[:3])
        self._rebuild_edges()
        return new

    def _rebuild_edges(self) -> None:
        g = self._graph
        g.remove_edges_from(list(g.edges))
        xyz = {k: np.asarray(r.pose[:3]) for k, r in self._records.items()}
        for k, r in self._records.items():
            for n in r.neighbours:
                if n in self._records:
                    g.add_edge(k, n, weight=float(np.linalg.norm(xyz[k] - xyz[n])), via="neighbour")
        by_room: dict[str, list[int]] = {}
        for k, r in self._records.items():
            by_room.setdefault(r.room, []).append(k)
        for ids in by_room.values():
            for a, b in combinations(sorted(ids), 2):
                if not g.has_edge(a, b):
                    g.add_edge(a, b, weight=float(np.linalg.norm(xyz[a] - xyz[b])), via="room")

    def route(self, from_room: str, to_room: str) -> Route:
        """Return the shortest route from any place of `from_room` to any place of `to_room`.

        Raises NoRoute (naming the rooms that have places) when a room has no place or the two
        are not connected.
        """
        src = [k for k, r in self._records.items() if r.room == from_room]
        dst = {k for k, r in self._records.items() if r.room == to_room}
        if not src or not dst:
            missing = from_room if not src else to_room
            raise NoRoute(
                f"no place in room {missing!r} yet; rooms with places: {', '.join(self.rooms)}"
            )
        g = self._graph.copy()
        g.add_node("_start")
        for k in src:
            g.add_edge("_start", k, weight=0.0)
        try:
            lengths, paths = nx.single_source_dijkstra(g, "_start", weight="weight")
        except nx.NetworkXException as exc:  # pragma: no cover - networkx internal failure
            raise NoRoute(str(exc)) from None
        reach = [k for k in dst if k in lengths]
        if not reach:
            raise NoRoute(f"rooms {from_room!r} and {to_room!r} are not connected by known places")
        end = min(reach, key=lambda k: (lengths[k], k))
        path = tuple(int(k) for k in paths[end][1:])
        return Route(path, tuple(self._records[k].room for k in path), float(lengths[end]))

    def to_dict(self) -> dict[str, Any]:
        """Return the map as a GeoJSON-like FeatureCollection: places (Point) and edges
        (LineString)."""
        feats: list[dict[str, Any]] = []
        for k in sorted(self._records):
            r = self._records[k]
            feats.append(
                {
                    "type": "Feature",
                    "geometry": {"type": "Point", "coordinates": [r.pose[0], r.pose[1]]},
                    "properties": {
                        "id": k,
                        "kind": "place",
                        "name": r.name,
                        "room": r.room,
                        "pose": list(r.pose),
                        "neighbours": list(r.neighbours),
                    },
                }
            )
        for a, b, data in sorted(self._graph.edges(data=True)):
            pa, pb = self._records[a].pose, self._records[b].pose
            feats.append(
                {
                    "type": "Feature",
                    "geometry": {
                        "type": "LineString",
                        "coordinates": [[pa[0], pa[1]], [pb[0], pb[1]]],
                    },
                    "properties": {
                        "kind": "edge",
                        "from": a,
                        "to": b,
                        "length_m": data["weight"],
                        "via": data["via"],
                    },
                }
            )
        return {"type": "FeatureCollection", "features": feats}
