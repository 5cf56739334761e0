"""The twin's walls and furniture as occluders, and the coverage map's visibility against what
the renderer's cameras actually see."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.localization import NetworkCamera, coverage_map
from core.localization.occluders import line_of_sight
from core.sim import Renderer, camera_model, default_scene
from core.sim.occluders import scene_occluders


def test_default_home_occluders():
    scene = default_scene()
    occ = scene_occluders(scene)
    # Walls: south, east, north one piece each; west 2 pieces and a lintel (one door); the
    # middle wall 3 pieces and 2 lintels; kitchen/bedroom 2 pieces and a lintel: 14. Furniture 8.
    assert occ.kinds.count("wall") == 14 and occ.kinds.count("furniture") == 8
    assert set(occ.names) >= {f.name for f in scene.furniture} | {"west", "north"}
    k = occ.names.index("bed")  # 2.0 x 1.6 turned by 90 deg about (6.9, 4.9), 0.5 m high
    assert np.allclose(np.sort(occ.footprints()[k], axis=0)[[0, -1]], [[6.1, 3.9], [7.7, 5.9]])
    assert np.allclose(occ.z[k], [0.0, 0.5])
    lintels = [i for i in range(len(occ)) if occ.kinds[i] == "wall" and occ.z[i, 0] > 0]
    assert sorted(np.round(occ.z[lintels, 0], 3).tolist()) == [2.05, 2.05, 2.05, 2.1]


@pytest.fixture(scope="module")
def home():
    scene = default_scene()
    # The reference renders without supersampling: its depth buffer then holds each face's
    # exact depth at the canvas pixel centres, whereas the anti-aliased layer keeps the nearest
    # of 2 x 2 sub-pixels, which on floor seen at grazing angles 7 m away is a few cm nearer
    # than the floor point itself and makes `sees` (2 cm tolerance) call the floor hidden by
    # itself.
    renderer = Renderer(scene, supersample=1)
    cams = []
    for spec in scene.cameras:
        m = camera_model(spec)  # the true cameras: the reference is the renderer itself
        cams.append(NetworkCamera.from_pose(m.K, m.dist, m.T_world_camera, (m.width, m.height)))
    return scene, renderer, cams


@pytest.mark.parametrize("height", [0.0, 0.36])  # the floor (people's feet), the robot marker
def test_map_visibility_agrees_with_what_the_renderer_sees(home, height):
    scene, renderer, cams = home
    occ = scene_occluders(scene)
    m = coverage_map(cams, (0.0, 8.0), (0.0, 6.0), spacing=0.1, height=height, occluders=occ)
    free = coverage_map(cams, (0.0, 8.0), (0.0, 6.0), spacing=0.1, height=height)
    gx, gy = np.meshgrid(m.x, m.y)
    X = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, height)])
    seen = np.stack([renderer.sees(spec.name, X) for spec in scene.cameras])
    ours = m.seen_by.reshape(len(cams), -1)
    before = free.seen_by.reshape(len(cams), -1)

    # Without occlusion the map claimed more than half of the camera-cell pairs it counted
    # that the renderer shows hidden (the complaint); with it, its share of hidden
    # pairs is the renderer's within 1 %.
    rendered_hidden = np.count_nonzero(before & ~seen) / np.count_nonzero(before)
    assert rendered_hidden > 0.5
    assert np.mean(before == seen) < 0.75
    assert abs(m.fraction_hidden() - rendered_hidden) < 0.01

    # Agreement pair by pair. Disagreement is allowed only where the visibility itself changes
    # within 5 cm of the cell (the edge of an occluder's shadow, a cell centre on a wall face,
    # or the image border): the renderer decides on a depth buffer of pixels about 2.5 cm wide
    # on the floor 7 m away, stretched by the grazing angle, with a 2 cm depth tolerance.
    agree = ours == seen
    assert agree.mean() >= 0.99, f"{agree.mean():.4f}"
    ring = 0.05 * np.array(
        [[math.cos(a), math.sin(a), 0.0] for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)]
    )
    for k, b in np.argwhere(~agree):
        Q = X[b] + ring
        near = cams[k].in_view(Q) & line_of_sight(cams[k].center[None], Q, occ)[0]
        assert np.any(near != ours[k, b]), f"camera {k} at {X[b]}: not at a visibility edge"
