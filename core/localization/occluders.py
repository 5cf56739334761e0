"""What hides the floor from a camera: walls (with door openings) and furniture, as plain boxes.

Every occluder is a vertical box (a right prism on a rectangle): its footprint is a rectangle of
half sizes (a, b) centred at (cx, cy) and turned by `yaw` about world Z, and it spans the
heights z0..z1. A wall from `start` to `end` of `thickness` is such a box per solid span between
its doors, plus a lintel over each door lower than the wall; furniture is one box standing on
the floor. World frame: right-handed, Z up, the floor Z = 0, metres.

`line_of_sight(origins, points, occluders)` says, for every origin (a camera's optical centre)
and every point, whether the segment between them crosses no box. It is the slab test of
Kay & Kajiya ("Ray tracing complex scenes", SIGGRAPH 1986) in each box's own frame: the segment
O + t (P - O), t in [0, 1], meets the box where the three slab intervals of t overlap.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core._validate import as_points
from core.errors import InvalidInput

Array = NDArray[np.float64]
OccluderKind = Literal["wall", "furniture"]

# Segment-box tests per chunk of the (origins x points x boxes) product: 4 MB per float64
# temporary (a few tens of MB in all), whatever the map's size; the default home's map at
# 0.1 m (4 cameras x 4,800 cells x 22 boxes) is one chunk.
_CHUNK_ELEMENTS = 500_000


@dataclass(frozen=True)
class DoorGap:
    """An opening in a wall: from `offset` to `offset + width` metres along the wall (from its
    start), from the floor up to `height` metres."""

    offset: float
    width: float
    height: float


@dataclass(frozen=True)
class Box:
    """A vertical box: footprint centre (x, y), size (length along its x, width along its y,
    height) metres, turned by `yaw` radians about Z, its bottom at `z0` metres."""

    centre: tuple[float, float]
    size: tuple[float, float, float]
    yaw: float = 0.0
    z0: float = 0.0
    name: str = ""
    kind: OccluderKind = "furniture"


@dataclass(frozen=True)
class Wall:
    """A straight wall from `start` to `end` (x, y metres), `height` and `thickness` metres,
    with door openings. Like a drawn plan, it reaches half a thickness past both ends so that
    walls meeting at a corner close it."""

    start: tuple[float, float]
    end: tuple[float, float]
    height: float
    thickness: float = 0.1
    doors: tuple[DoorGap, ...] = ()
    name: str = ""

    def boxes(self) -> list[Box]:
        """Return the solid parts of the wall as boxes: full height between and beside the
        doors, and a lintel over each door lower than the wall."""
        a = np.asarray(self.start, dtype=np.float64)
        b = np.asarray(self.end, dtype=np.float64)
        length = float(np.linalg.norm(b - a))
        values = (*a, *b, self.height, self.thickness)
        if not all(math.isfinite(v) for v in values) or length < 1e-3:
            raise InvalidInput(
                f"wall {self.name or self.start}: start and end must be finite and at least "
                f"1 mm apart, got {self.start} -> {self.end}"
            )
        if not (self.height > 0 and self.thickness > 0):
            raise InvalidInput(
                f"wall {self.name or self.start}: height and thickness must be positive metres"
            )
        u = (b - a) / length
        yaw = math.atan2(u[1], u[0])
        half = self.thickness / 2
        spans: list[tuple[float, float, float, float]] = []
        pos = 0.0
        for d in sorted(self.doors, key=lambda d: d.offset):
            if d.offset < pos - 1e-9 or d.width <= 0 or d.offset + d.width > length + 1e-9:
                raise InvalidInput(
                    f"wall {self.name or self.start}: doors must not overlap and must lie on "
                    f"the wall (length {length:.3f} m), got offset {d.offset}, width {d.width}"
                )
            if d.offset > pos:
                spans.append((pos, d.offset, 0.0, self.height))
            if d.height < self.height:
                spans.append((d.offset, d.offset + d.width, max(d.height, 0.0), self.height))
            pos = d.offset + d.width
        if pos < length:
            spans.append((pos, length, 0.0, self.height))
        out = []
        for s0, s1, z0, z1 in spans:
            s0e = s0 - half if s0 <= 0 else s0
            s1e = s1 + half if s1 >= length else s1
            c = a + u * (s0e + s1e) / 2
            out.append(
                Box(
                    centre=(float(c[0]), float(c[1])),
                    size=(s1e - s0e, self.thickness, z1 - z0),
                    yaw=yaw,
                    z0=z0,
                    name=self.name,
                    kind="wall",
                )
            )
        return out


@dataclass(frozen=True, eq=False)
class Occluders:
    """N vertical boxes packed as arrays (batch axis first), what `line_of_sight` tests.

    `centre` (N, 2) metres; `half_size` (N, 2) half length along the box's x and half width
    along its y, metres; `yaw` (N,) radians about Z; `z` (N, 2) bottom and top, metres;
    `names` and `kinds` ("wall" or "furniture") per box (empty: unnamed furniture).
    `Occluders.build` makes them from `Wall` and `Box` records.
    """

    centre: Array
    half_size: Array
    yaw: Array
    z: Array
    names: tuple[str, ...] = ()
    kinds: tuple[OccluderKind, ...] = ()
    _cos_sin: Array = field(init=False, repr=False)

    def __post_init__(self) -> None:
        try:
            n = np.asarray(self.centre, dtype=np.float64).reshape(-1, 2).shape[0]
            arrays = {
                "centre": np.asarray(self.centre, dtype=np.float64).reshape(n, 2),
                "half_size": np.asarray(self.half_size, dtype=np.float64).reshape(n, 2),
                "yaw": np.asarray(self.yaw, dtype=np.float64).reshape(n),
                "z": np.asarray(self.z, dtype=np.float64).reshape(n, 2),
            }
        except (TypeError, ValueError) as exc:
            raise InvalidInput(
                "occluders need centre (N, 2), half_size (N, 2), yaw (N,) and z (N, 2) "
                f"numeric arrays: {exc}"
            ) from None
        for name, a in arrays.items():
            if not np.all(np.isfinite(a)):
                raise InvalidInput(f"occluder {name} contains NaN or infinite values")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        names = tuple(self.names) or ("",) * n
        kinds = tuple(self.kinds) or ("furniture",) * n
        if len(names) != n or len(kinds) != n:
            raise InvalidInput(
                f"occluders need one name and one kind per box: {len(names)} names, "
                f"{len(kinds)} kinds for {n} boxes"
            )
        if any(k not in ("wall", "furniture") for k in kinds):
            raise InvalidInput(f"occluder kinds must be 'wall' or 'furniture', got {set(kinds)}")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "kinds", kinds)
        if np.any(self.half_size <= 0) or np.any(self.z[:, 1] <= self.z[:, 0]):
            raise InvalidInput("every occluder box needs a positive size and height (z1 > z0)")
        cs = np.column_stack([np.cos(self.yaw), np.sin(self.yaw)])
        cs.setflags(write=False)
        object.__setattr__(self, "_cos_sin", cs)

    def __len__(self) -> int:
        return len(self.names)

    @classmethod
    def build(cls, walls: Iterable[Wall] = (), boxes: Iterable[Box] = ()) -> Occluders:
        """Return the occluders of walls (split at their doors) and furniture boxes."""
        parts = [b for w in walls for b in w.boxes()] + list(boxes)
        for b in parts:
            values = (*b.centre, *b.size, b.yaw, b.z0)
            if not all(math.isfinite(v) for v in values) or min(b.size) <= 0:
                raise InvalidInput(
                    f"box {b.name or b.centre}: centre, size, yaw, z0 must be finite and the "
                    f"size positive, got size {b.size}"
                )
        return cls(
            centre=np.array([b.centre for b in parts], dtype=np.float64).reshape(-1, 2),
            half_size=np.array([b.size[:2] for b in parts], dtype=np.float64).reshape(-1, 2) / 2,
            yaw=np.array([b.yaw for b in parts], dtype=np.float64),
            z=np.array([(b.z0, b.z0 + b.size[2]) for b in parts], dtype=np.float64).reshape(-1, 2),
            names=tuple(b.name for b in parts),
            kinds=tuple(b.kind for b in parts),
        )

    def footprints(self) -> Array:
        """Return the boxes' footprint corners (N, 4, 2) metres, counter-clockwise."""
        sx = np.array([-1.0, 1.0, 1.0, -1.0])
        sy = np.array([-1.0, -1.0, 1.0, 1.0])
        lx = sx[None, :] * self.half_size[:, :1]  # (N, 4) in the box frame
        ly = sy[None, :] * self.half_size[:, 1:]
        c, s = self._cos_sin[:, :1], self._cos_sin[:, 1:]
        x = self.centre[:, :1] + c * lx - s * ly
        y = self.centre[:, 1:] + s * lx + c * ly
        return np.stack([x, y], axis=-1)

    def to_list(self) -> list[dict[str, object]]:
        """Return a JSON-ready list: name, kind, footprint corners (4 x [x, y]) and [z0, z1]."""
        corners = self.footprints()
        return [
            {
                "name": self.names[i],
                "kind": self.kinds[i],
                "footprint": corners[i].tolist(),
                "z": self.z[i].tolist(),
            }
            for i in range(len(self))
        ]


def line_of_sight(
    origins: ArrayLike,
    points: ArrayLike,
    occluders: Occluders,
    *,
    tolerance: float = 0.005,
) -> NDArray[np.bool_]:
    """Return clear (C, B): whether the segment from origins[c] (C, 3) to points[b] (B, 3),
    metres, crosses none of the occluder boxes.

    The segment O + t D, D = P - O, lies inside box k for t in the intersection of its three
    slab intervals [(lo_i - o_i) / d_i, (hi_i - o_i) / d_i] (sorted), taken in the box frame
    (Kay & Kajiya 1986). It is hidden when that interval [t_in, t_out] is not empty, reaches
    past the origin (t_out > 0) and starts more than `tolerance` metres before the point:
    t_in < 1 - tolerance / |D|. So a point on a box's face seen from outside (a target on a
    table top, a cell centre on a wall face) stays visible, and a point inside a box (under a
    wardrobe, within a wall) is hidden. Vectorised over C x B x N; chunked over the points.
    """
    O = as_points(origins, 3, "origins")
    P = as_points(points, 3, "points")
    tol = float(tolerance)
    if not (math.isfinite(tol) and tol >= 0):
        raise InvalidInput(f"tolerance must be a finite number of metres >= 0, got {tolerance}")
    clear = np.ones((O.shape[0], P.shape[0]), dtype=np.bool_)
    n = len(occluders)
    if n == 0 or O.shape[0] == 0 or P.shape[0] == 0:
        return clear
    step = max(1, _CHUNK_ELEMENTS // (O.shape[0] * n))
    for b0 in range(0, P.shape[0], step):
        clear[:, b0 : b0 + step] = ~_hidden(O, P[b0 : b0 + step], occluders, tol)
    return clear


def _to_box_frames(X: Array, occ: Occluders) -> tuple[Array, Array]:
    """Return the box-frame x and y (M, N) of world points X (M, 3) for each of the N boxes."""
    dx = X[:, None, 0] - occ.centre[None, :, 0]
    dy = X[:, None, 1] - occ.centre[None, :, 1]
    c, s = occ._cos_sin[:, 0], occ._cos_sin[:, 1]
    return c * dx + s * dy, -s * dx + c * dy


def _slab(o: Array, d: Array, lo: Array, hi: Array) -> tuple[Array, Array]:
    """Return the t interval (t_lo, t_hi) in which o + t d lies within [lo, hi], elementwise.

    A direction component of exactly zero is replaced by a tiny positive number: the interval
    is then (-inf, inf)-like when o is inside the slab and empty-like when it is outside, with
    no NaN (the numerators are then finite and the quotients at most +-inf).
    """
    d = np.where(d == 0.0, 1e-300, d)
    with np.errstate(over="ignore", divide="ignore"):
        inv = 1.0 / d
        t1 = (lo - o) * inv
        t2 = (hi - o) * inv
    return np.minimum(t1, t2), np.maximum(t1, t2)


def _hidden(O: Array, P: Array, occ: Occluders, tol: float) -> NDArray[np.bool_]:
    """Return hidden (C, B) for origins O (C, 3), points P (B, 3) and all boxes (see above)."""
    ox, oy = _to_box_frames(O, occ)  # (C, N)
    px, py = _to_box_frames(P, occ)  # (B, N)
    ox, oy = ox[:, None, :], oy[:, None, :]  # (C, 1, N)
    dx = px[None] - ox  # (C, B, N)
    dy = py[None] - oy
    oz = O[:, None, None, 2]
    dz = P[None, :, None, 2] - oz  # (C, B, 1)
    hx, hy = occ.half_size[:, 0], occ.half_size[:, 1]
    tx0, tx1 = _slab(ox, dx, -hx, hx)
    ty0, ty1 = _slab(oy, dy, -hy, hy)
    tz0, tz1 = _slab(oz, dz, occ.z[:, 0], occ.z[:, 1])
    t_in = np.maximum(np.maximum(tx0, ty0), tz0)
    t_out = np.minimum(np.minimum(tx1, ty1), tz1)
    length = np.sqrt(dx[..., :1] ** 2 + dy[..., :1] ** 2 + dz**2)  # rotations keep lengths
    t_last = 1.0 - tol / np.maximum(length, 1e-12)
    hit = (t_in <= t_out) & (t_out > 0.0) & (t_in < t_last)
    return np.asarray(np.any(hit, axis=2))
