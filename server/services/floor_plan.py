"""Which floor plan stands in a space: the digital twin's home scene (walls with doors,
furniture) when the space is the twin's, else none (the registry holds only room polygons).

Used by the coverage map (server.api.maps) and path planning (server.api.paths,
server.services.paths).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from core.sim import Scene, default_scene
from server.db.models import Room, Space


def twin_scene_of(twin: Any, session: Session, space_id: int) -> Scene | None:
    """Return the twin scene whose walls and furniture stand in the space, or None.

    `twin` is the running twin (server.services.twin, with `.space_id` and `.scene`) or None.
    Its scene when the twin lives in this space; otherwise the default home when the space is
    its registered copy (the service was run with the twin before): same name and the very
    same rooms, polygon for polygon.
    """
    if twin is not None and twin.space_id == space_id:
        return twin.scene
    scene = default_scene()
    space = session.get(Space, space_id)
    if space is None or space.name != scene.name:
        return None
    # Sorted here, not by the database, whose collation may order names differently.
    rows = sorted(
        session.execute(select(Room.name, Room.polygon).where(Room.space_id == space_id)).all(),
        key=lambda row: str(row[0]),
    )
    want = sorted(scene.rooms, key=lambda r: r.name)
    same = len(rows) == len(want) and all(
        name == r.name
        and np.shape(polygon) == (len(r.polygon), 2)
        and np.allclose(polygon, r.polygon, rtol=0.0, atol=1e-9)
        for (name, polygon), r in zip(rows, want, strict=False)
    )
    return scene if same else None
