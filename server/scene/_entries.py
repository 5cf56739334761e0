"""What the scene is told: the registry's rooms, cameras, arms, projector, landmarks and map
entries as the scene takes them (server.services.scene_sync builds them from rows).

Each is a frozen dataclass of plain values as the registry stores them (nested lists or
arrays, metres, radians); the scene checks their values (a pose that is not rigid, a polygon
that is not one) when it is given them and raises InvalidInput naming what is wrong.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

# A matrix as stored (nested lists) or as computed (an array).
Matrix = Sequence[Sequence[float]] | NDArray[np.float64]
Vector = Sequence[float] | NDArray[np.float64]


@dataclass(frozen=True)
class RoomEntry:
    """A room of the floor plan: its id, name and polygon [[x, y], ...] (m, floor Z = 0)."""

    id: int
    name: str
    polygon: Matrix


@dataclass(frozen=True)
class CameraEntry:
    """A registry camera: id, name, image size (pixels), K (3x3 pixels, None: not calibrated)
    and T_world_camera (4x4 camera-to-world, OpenCV camera axes; None: not placed)."""

    id: int
    name: str
    width: int
    height: int
    K: Matrix | None = None
    T_world_camera: Matrix | None = None


@dataclass(frozen=True)
class ArmEntry:
    """An arm on the robot drawn as `agent`: its id (scene key), name, DH parameters
    {a, d, alpha, offset?}, joint limits (6, 2), tool (4, 4), home (6,), mount T_robot_arm
    (4, 4) and joint values q (6,) rad (None: home)."""

    id: str
    agent: str
    name: str
    dh: Mapping[str, Vector]
    limits: Matrix
    tool: Matrix
    home: Vector
    T_robot_arm: Matrix
    q: Vector | None = None


@dataclass(frozen=True)
class ProjectorEntry:
    """The ceiling projector: its name, mount pose T_world_projector (4x4, the pan-tilt base)
    and the floor point [x, y] (m) its beam is drawn to (None: no beam)."""

    name: str
    T_world_projector: Matrix
    spot: Vector | None = None


@dataclass(frozen=True)
class LandmarkEntry:
    """A placed landmark: its id (scene key), name, kind ("object", "signpost" or another
    registry kind), printed size (m) and pose T_world_landmark (4x4)."""

    id: int | str
    name: str
    kind: str
    size: float
    T_world_landmark: Matrix


@dataclass(frozen=True)
class SemanticObjectEntry:
    """An object of the semantic map: its key ("space:mark"), name, class, room and its
    mark's fused world pose T_world_mark (4x4)."""

    id: str
    name: str
    object_class: str
    room: str
    T_world_mark: Matrix


@dataclass(frozen=True)
class PlaceEntry:
    """A place of the navigation map: its key ("space:mark"), name, room and position
    (x, y[, z]) m, the pose its signpost carries."""

    id: str
    name: str
    room: str
    position: Vector
