"""The laser spot's sub-pixel centre in an onboard image, and "not seen"."""

from __future__ import annotations

import numpy as np

from core.navigation import detect_laser_spot

H, W = 240, 320  # a quarter of the onboard camera's frame keeps the test fast


def _floor(rng: np.random.Generator) -> np.ndarray:
    # Grey-beige tiles with grout and sensor noise (sigma 2 grey levels).
    img = np.zeros((H, W, 3), np.float64)
    yy, xx = np.mgrid[0:H, 0:W]
    tile = ((xx // 40 + yy // 40) % 2).astype(float)
    base = (
        np.array([175.0, 195.0, 205.0]) * (1 - tile[..., None])
        + np.array([130.0, 150.0, 160.0]) * tile[..., None]
    )
    img[:] = base
    img[(xx % 40 < 2) | (yy % 40 < 2)] = (95, 105, 110)
    return img + rng.normal(0.0, 2.0, img.shape)


def _spot(img: np.ndarray, centre: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    yy, xx = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
    g = np.exp(-((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) / (2 * sigma**2))
    out = img.copy()
    out[..., 2] = out[..., 2] * (1 - g) + 255 * g  # red saturates
    out[..., 1] *= 1 - 0.7 * g
    out[..., 0] *= 1 - 0.7 * g
    return out


def _u8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def test_subpixel_centre_of_a_rendered_spot() -> None:
    rng = np.random.default_rng(0)
    errs = []
    for _ in range(40):
        c = rng.uniform([20, 20], [W - 20, H - 20])
        det = detect_laser_spot(_u8(_spot(_floor(rng), c)))
        assert det is not None
        errs.append(det.pixel - c)
    rms = float(np.sqrt(np.mean(np.square(errs))))
    # Measured ~0.015 px here; the twin's path-following scenario assumes a conservative
    # 0.3 px per axis (SPOT_PIXEL_SIGMA) for blur, speckle and partly hidden spots.
    assert rms < 0.05
    assert np.max(np.abs(errs)) < 0.15


def test_no_spot_or_two_spots_is_not_seen() -> None:
    rng = np.random.default_rng(1)
    floor = _floor(rng)
    assert detect_laser_spot(_u8(floor)) is None
    two = _spot(_spot(floor, np.array([100.0, 100.0])), np.array([250.0, 180.0]))
    assert detect_laser_spot(_u8(two)) is None
    # A large red object (a rug) is not a laser spot.
    rug = floor.copy()
    rug[100:200, 100:250] = (20, 20, 230)  # 15,000 px
    assert detect_laser_spot(_u8(rug)) is None


def test_on_off_difference_finds_a_spot_that_saturates_a_bright_floor() -> None:
    rng = np.random.default_rng(2)
    floor = np.full((H, W, 3), (190.0, 200.0, 210.0))  # bright beige: red near saturation
    c = np.array([123.4, 87.8])
    yy, xx = np.mgrid[0:H, 0:W]
    g = np.exp(-((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / (2 * 1.2**2))
    on = floor.copy()
    on[..., 2] += 300.0 * g
    off_img = _u8(floor + rng.normal(0.0, 2.0, floor.shape))
    on_img = _u8(on + rng.normal(0.0, 2.0, floor.shape))
    # Saturated red on a bright floor is barely redder than the floor: one image misses it.
    assert detect_laser_spot(on_img) is None
    det = detect_laser_spot(on_img, background=off_img)
    assert det is not None
    # The saturated top is flat but symmetric: its weighted centroid stays sub-pixel exact.
    assert np.linalg.norm(det.pixel - c) < 0.1
