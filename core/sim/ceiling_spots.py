"""The projector's spot as the ceiling cameras see it, in the twin.

`spots_in_images`: each ceiling camera's frame of the home is rendered (core.sim.render) with
the laser's light added where the spot's image falls, when the camera sees it (in view, not
hidden by walls or furniture), and the spot is detected in it by
core.navigation.detect_laser_spot. `spots_projected`: the spots' true projections plus the
centroid's pixel noise (CEILING_PIXEL_SIGMA), for studies without images.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from core.localization import NetworkCamera
from core.navigation import detect_laser_spot
from core.sim.motion import WorldState
from core.sim.network_cameras import true_cameras
from core.sim.render import renderer_for
from core.sim.scene import Scene

Array = NDArray[np.float64]

CEILING_PIXEL_SIGMA = 0.5
LASER_BLOB_SIGMA = 1.2


def _seen(scene: Scene, cam: NetworkCamera, X: Array) -> NDArray[np.bool_]:
    from core.localization.occluders import line_of_sight
    from core.sim.occluders import scene_occluders

    seen: NDArray[np.bool_] = (
        cam.in_view(X) & line_of_sight(cam.center[None], X, scene_occluders(scene))[0]
    )
    return seen


def spots_projected(
    scene: Scene, names: list[str], spots: Array, rng: np.random.Generator
) -> tuple[Array, NDArray[np.bool_]]:
    """Return (pixels (C, N, 2), visible (C, N)): each spot through each true lens where the
    camera sees it, plus the centroid's pixel noise (CEILING_PIXEL_SIGMA)."""
    X = np.column_stack([spots, np.zeros(len(spots))])
    pixels = np.zeros((len(names), len(X), 2))
    vis = np.zeros((len(names), len(X)), bool)
    for k, cam in enumerate(true_cameras(scene, names)):
        seen = _seen(scene, cam, X)
        uv = cam.project(X) + rng.normal(0.0, CEILING_PIXEL_SIGMA, (len(X), 2))
        pixels[k, seen] = uv[seen]
        vis[k] = seen
    return pixels, vis


def spots_in_images(
    scene: Scene, names: list[str], spots: Array, rng: np.random.Generator
) -> tuple[Array, NDArray[np.bool_]]:
    """Return (pixels (C, N, 2), visible (C, N)) of the spots detected in rendered images.

    Each camera's frame of the home (without the robot) is rendered twice with independent
    sensor noise: laser off, and laser on, with the laser's red light added where the spot's
    image falls (a Gaussian blob of LASER_BLOB_SIGMA px: a spot's glare spans a few pixels
    however small the spot; on the bright floor the red channel saturates).
    core.navigation.detect_laser_spot finds it in the on - off difference (the projector
    blinks the laser) or reports it not seen. A spot hidden from a camera adds no light.
    """
    renderer = renderer_for(scene)
    X = np.column_stack([spots, np.zeros(len(spots))])
    people = tuple((float(w.waypoints[0][0]), float(w.waypoints[0][1])) for w in scene.people)
    pixels = np.zeros((len(names), len(X), 2))
    vis = np.zeros((len(names), len(X)), bool)
    for k, (name, cam) in enumerate(zip(names, true_cameras(scene, names), strict=True)):
        seen = _seen(scene, cam, X)
        if not np.any(seen):
            continue
        base = renderer.render(name, WorldState(0.0, None, people), noise=None).image
        uv = cam.project(X)
        H, W = base.shape[:2]
        r = math.ceil(5 * LASER_BLOB_SIGMA)

        def develop(img: NDArray[np.float32]) -> NDArray[np.uint8]:
            noise = rng.standard_normal(img.shape, dtype=np.float32)
            noisy = img + 2.0 * noise  # sensor noise, 2 grey levels
            return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)

        # One laser-off frame per camera serves every spot (the views do not change).
        off = develop(base.astype(np.float32))

        for i in np.flatnonzero(seen):
            # The blob within 5 sigma of its centre (beyond, its light is below a grey level).
            x0, y0 = max(int(uv[i, 0]) - r, 0), max(int(uv[i, 1]) - r, 0)
            x1, y1 = min(int(uv[i, 0]) + r + 1, W), min(int(uv[i, 1]) + r + 1, H)
            yy, xx = np.mgrid[y0:y1, x0:x1]
            g = np.exp(-((xx - uv[i, 0]) ** 2 + (yy - uv[i, 1]) ** 2) / (2 * LASER_BLOB_SIGMA**2))
            on = base.astype(np.float32)
            on[y0:y1, x0:x1, 2] += 300.0 * g  # red light: the red channel rises (saturates)
            on[y0:y1, x0:x1, 1] += 10.0 * g
            det = detect_laser_spot(develop(on), background=off)
            if det is not None:
                pixels[k, i] = det.pixel
                vis[k, i] = True
    return pixels, vis
