"""Textures of the twin's planar things: tiled floors, the marker disc, chessboards."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from core.sim.scene import Board, Tiles, TopMarker

Array = NDArray[np.float64]
Image = NDArray[Any]  # uint8 images; typed loosely because cv2 returns its own array type

# --------------------------------------------------------------------------------------------
# Textures


@dataclass(frozen=True, eq=False)
class _Texture:
    """A texture pyramid on a world plane: texel (s, t) of level 0 sits at o + s u + t v
    (world metres); level l is cv2.pyrDown applied l times, so s_0 = 2^l s_l."""

    levels: tuple[Image, ...]
    o: Array
    u: Array
    v: Array


def _pyramid(img: Image, min_size: int = 8) -> tuple[Image, ...]:
    levels = [img]
    while min(levels[-1].shape[:2]) >= 2 * min_size:
        levels.append(cv2.pyrDown(levels[-1]))
    return tuple(levels)


def _splitmix(x: NDArray[np.uint64]) -> NDArray[np.float64]:
    # A counter-based hash (SplitMix64), uniform in [0, 1): tile colours depend only on the
    # tile's indices and the seed, so tiles continue seamlessly across rooms.
    with np.errstate(over="ignore"):
        z = x + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def _bgr(rgb: tuple[int, int, int]) -> Array:
    return np.array(rgb[::-1], dtype=np.float64)


def _tile_texture(tiles: Tiles, lo: Array, hi: Array, salt: int) -> _Texture:
    """Return the floor texture over the rectangle lo..hi (x, y metres), world-anchored tiles."""
    ppm = tiles.pixels_per_metre
    nx = max(2, math.ceil((hi[0] - lo[0]) * ppm))
    ny = max(2, math.ceil((hi[1] - lo[1]) * ppm))
    x = lo[0] + (np.arange(nx) + 0.5) / ppm
    y = lo[1] + (np.arange(ny) + 0.5) / ppm
    X, Y = np.meshgrid(x, y)
    fx, fy = X / tiles.size, Y / tiles.size
    ti, tj = np.floor(fx), np.floor(fy)
    checker = ((ti + tj) % 2 == 0)[..., None]
    colour = np.where(checker, _bgr(tiles.colour_a), _bgr(tiles.colour_b))
    key = (
        (ti.astype(np.int64) * 73856093)
        ^ (tj.astype(np.int64) * 19349663)
        ^ (tiles.seed * 83492791)
    )
    jitter = 1.0 + tiles.jitter * (2.0 * _splitmix(key.astype(np.uint64)) - 1.0)
    img = colour * jitter[..., None]
    rng = np.random.default_rng([tiles.seed, salt])
    img += rng.normal(0.0, 3.0, size=img.shape)  # fine grain gives texture inside the tiles
    g = tiles.grout_width / 2.0 / tiles.size
    grout = (np.minimum(fx - ti, ti + 1 - fx) < g) | (np.minimum(fy - tj, tj + 1 - fy) < g)
    img[grout] = _bgr(tiles.grout_colour)
    tex = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    o = np.array([lo[0] + 0.5 / ppm, lo[1] + 0.5 / ppm, 0.0])
    return _Texture(_pyramid(tex), o, np.array([1 / ppm, 0.0, 0.0]), np.array([0.0, 1 / ppm, 0.0]))


def _disc_texture(marker: TopMarker, texels: int = 96) -> tuple[Image, float]:
    """Return a BGRA texture (texels x texels) of the disc with area-coverage alpha, and the
    side of the square it covers in metres (the disc's diameter plus a transparent border)."""
    side = 2.0 * marker.radius * 1.25
    ss = 4
    c = (np.arange(texels * ss) + 0.5) / (texels * ss) * side - side / 2
    X, Y = np.meshgrid(c, c)
    inside = (X * X + Y * Y <= marker.radius**2).astype(np.float64)
    alpha = inside.reshape(texels, ss, texels, ss).mean(axis=(1, 3))
    img = np.empty((texels, texels, 4), np.uint8)
    img[..., :3] = _bgr(marker.colour).astype(np.uint8)
    img[..., 3] = np.rint(alpha * 255).astype(np.uint8)
    return img, side


def _board_texture(board: Board, per_square: int = 32) -> Image:
    """Return the chessboard (with its white margin) as a BGR texture, `per_square` texels per
    square; squares are whole texels, so the corners sit exactly on texel boundaries."""
    cols, rows = board.inner_corners
    m = round(board.margin * per_square)
    w, h = (cols + 1) * per_square, (rows + 1) * per_square
    jj, ii = np.meshgrid(np.arange(w) // per_square, np.arange(h) // per_square)
    sq = np.where((ii + jj) % 2 == 0, 20, 235).astype(np.uint8)
    img = np.full((h + 2 * m, w + 2 * m), 235, np.uint8)
    img[m : m + h, m : m + w] = sq
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
