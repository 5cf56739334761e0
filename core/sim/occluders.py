"""The twin's walls and furniture as occluders of the coverage map (core.localization.occluders).

The boxes are those the renderer draws (core.sim.render): each wall split at its doors with
lintels above them and extended half a thickness past its ends, each piece of furniture a box
on the floor turned by its yaw. The floor plan is what an installer knows of a home, not the
twin's hidden truth (camera calibration, people), so a map may use it.
"""

from __future__ import annotations

from core.localization.occluders import Box, DoorGap, Occluders, Wall
from core.sim.scene import Scene


def scene_occluders(scene: Scene) -> Occluders:
    """Return the occluders of a scene: its walls (with door openings) and its furniture."""
    walls = [
        Wall(
            start=w.start,
            end=w.end,
            height=w.height,
            thickness=w.thickness,
            doors=tuple(DoorGap(d.offset, d.width, d.height) for d in w.doors),
            name=w.name or f"wall {k}",
        )
        for k, w in enumerate(scene.walls)
    ]
    boxes = [
        Box(centre=f.centre, size=f.size, yaw=f.yaw, name=f.name, kind="furniture")
        for f in scene.furniture
    ]
    return Occluders.build(walls=walls, boxes=boxes)
