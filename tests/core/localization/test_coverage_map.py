"""The coverage-and-accuracy map."""

from __future__ import annotations

import json

import numpy as np
import pytest
from localization_scene import make_cameras

from core.errors import InvalidInput
from core.localization import NetworkCamera, coverage_map, cramer_rao_bound


def test_map_of_a_downward_camera_covers_its_footprint():
    # Vertical axis, no distortion: the image (640 x 480, f = 500) covers exactly the floor
    # rectangle |X - 2| <= 320 (H - h) / f, |Y - 1.5| <= 240 (H - h) / f (pixel edges at
    # -0.5 and 639.5 with c = 319.5).
    f, H = 500.0, 2.5
    K = np.array([[f, 0.0, 319.5], [0.0, f, 239.5], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [2.0, 1.5, H]
    cam = NetworkCamera.from_pose(K, None, T, (640, 480), name="down")
    m = coverage_map([cam], (0.0, 4.0), (0.0, 3.0), spacing=0.05, pixel_sigma=0.5)
    assert m.n_cameras.shape == (60, 80) and m.seen_by.shape == (1, 60, 80)
    assert np.allclose(m.x[:2], [0.025, 0.075]) and np.allclose(m.y[-1], 2.975)
    gx, gy = np.meshgrid(m.x, m.y)
    inside = (np.abs(gx - 2.0) < 320 * H / f) & (np.abs(gy - 1.5) < 240 * H / f)
    assert np.array_equal(m.n_cameras == 1, inside)
    assert np.allclose(m.crb_std[inside], np.sqrt(2) * 0.5 * H / f, rtol=1e-12)
    assert np.all(np.isinf(m.crb_std[~inside]))


def test_map_agrees_with_the_bound_and_serialises():
    cams = make_cameras(4)
    m = coverage_map(cams, (0.0, 8.0), (0.0, 6.0), spacing=0.25, height=0.3, pixel_sigma=0.5)
    gx, gy = np.meshgrid(m.x, m.y)
    b = cramer_rao_bound(cams, np.column_stack([gx.ravel(), gy.ravel()]), 0.3, pixel_sigma=0.5)
    assert np.array_equal(m.n_cameras.ravel(), b.n_cameras)
    assert np.array_equal(m.crb_std.ravel(), b.std)
    assert m.fraction_covered(2) > 0.9
    assert m.fraction_covered(1) >= m.fraction_covered(2) >= m.fraction_covered(4)
    d = json.loads(json.dumps(m.to_dict()))
    assert d["cameras"] == ["cam0", "cam1", "cam2", "cam3"]
    assert len(d["crb_std"]) == len(m.y) and len(d["crb_std"][0]) == len(m.x)


def test_map_rejects_bad_rectangles():
    cams = make_cameras(1)
    with pytest.raises(InvalidInput, match="min < max"):
        coverage_map(cams, (1.0, 0.0), (0.0, 1.0))
    with pytest.raises(InvalidInput, match="spacing"):
        coverage_map(cams, (0.0, 1.0), (0.0, 1.0), spacing=0.0)


def test_heatmap_is_black_where_blind_and_brighter_where_accurate():
    cams = make_cameras(2)
    # The strip y < 0 lies behind both cameras.
    m = coverage_map(cams, (0.0, 8.0), (-3.0, 6.0), spacing=0.25, height=0.3, pixel_sigma=0.5)
    img = m.heatmap()
    assert img.shape == (*m.crb_std.shape, 3) and img.dtype == np.uint8
    blind = ~np.isfinite(m.crb_std)
    assert blind.any() and np.all(img[blind] == 0)
    seen = np.argwhere(~blind)
    best = tuple(seen[np.argmin(m.crb_std[~blind])])
    worst = tuple(seen[np.argmax(m.crb_std[~blind])])
    # Viridis runs from dark blue to bright yellow: the best cell is the brighter one.
    assert img[best].astype(int).sum() > img[worst].astype(int).sum()
