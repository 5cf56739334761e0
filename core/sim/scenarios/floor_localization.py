"""Localisation scenarios of the twin: the ground estimators against the Cramer-Rao bound.

* `localization`: floor points seen by >= 2 of the twin's true cameras, pixels = projections
  plus Gaussian noise; the RMSE of the four ground estimators against the Cramer-Rao bound.
* `localization-images`: the same estimators on the marker detected in rendered images, with
  the measured pixel noise of the detector beside the errors.

Both give the estimators the twin's *true* cameras (their records say `"cameras_from":
"truth"`): they measure the estimators alone, against the Cramer-Rao bound of the same
cameras, with no calibration error in the way. What a calibrated home achieves is measured by
the scenarios that locate on the installed calibration (`tracking`, `tracking-async`,
`projector-calibration`: core.sim.network_cameras.calibrated_cameras).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.localization import (
    NetworkCamera,
    cramer_rao_bound,
    locate_ml,
    locate_monocular,
    triangulate_linear,
    triangulate_on_plane,
)
from core.localization.detect import MarkerDetectorConfig, detect_marker
from core.sim._floor import free_floor_grid
from core.sim.motion import Pose2D, world_state
from core.sim.render import CameraModel, Renderer, SensorNoise
from core.sim.scenarios.records import LocalizationResult
from core.sim.scene import Scene, default_scene

Array = NDArray[np.float64]

_DEFAULT_NOISE = SensorNoise()


def _true_network(renderer: Renderer) -> list[tuple[CameraModel, NetworkCamera]]:
    out = []
    for spec in renderer.scene.cameras:
        m = renderer.camera(spec.name)
        nc = NetworkCamera.from_pose(m.K, m.dist, m.T_world_camera, (m.width, m.height), m.name)
        out.append((m, nc))
    return out


def _estimator_rmse(
    net: list[NetworkCamera],
    pixels: Array,
    vis: NDArray[np.bool_],
    truth: Array,
    height: float,
    sigma: float,
    pixel_cov: Array | None = None,
) -> tuple[dict[str, float], float, int]:
    """Return the RMSE per estimator (metres), the CRB root mean trace for the cameras ML
    used, and the number of targets every estimator located."""
    kw: dict[str, Any] = {"pixel_sigma": sigma, "pixel_cov": pixel_cov}
    lin = triangulate_linear(net, pixels, visible=vis, **kw)
    con = triangulate_on_plane(net, pixels, height, visible=vis, min_cameras=2, **kw)
    ml = locate_ml(net, pixels, height, visible=vis, min_cameras=2, **kw)
    # Monocular: each target from the first camera that sees it.
    first = np.argmax(vis, axis=0)
    mono_xy = np.full((pixels.shape[1], 2), np.nan)
    for k, cam in enumerate(net):
        sel = first == k
        if np.any(sel):
            mono_xy[sel] = locate_monocular(cam, pixels[k, sel], height, pixel_sigma=sigma).xy
    ok = lin.valid & con.valid & ml.valid & np.all(np.isfinite(mono_xy), axis=1)

    def rmse(xy: Array) -> float:
        return float(np.sqrt(np.mean(np.sum((xy[ok] - truth[ok]) ** 2, axis=1))))

    crb = cramer_rao_bound(
        net,
        truth[ok],
        height,
        pixel_sigma=sigma,
        pixel_cov=None if pixel_cov is None else pixel_cov[:, ok],
        visible=vis[:, ok],
    )
    out = {"mono": rmse(mono_xy), "linear": rmse(lin.xy), "constrained": rmse(con.xy)}
    out["ml"] = rmse(ml.xy)
    return out, crb.root_mean_trace, int(ok.sum())


def localization(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    samples: int = 1500,
    sigma_px: float = 0.5,
    height: float = 0.36,
) -> LocalizationResult:
    """Return the estimators' RMSE on `samples` floor points at Z = `height` metres, each seen
    by >= 2 of the scene's (true) cameras, with pixels = projection + N(0, sigma_px^2 I)."""
    scene = scene or default_scene()
    rng = np.random.default_rng(seed)
    renderer = Renderer(scene)
    net = [nc for _, nc in _true_network(renderer)]
    if len(net) < 2:
        raise InvalidInput("the localization scenario needs a scene with >= 2 cameras")
    rooms = np.array([p for r in scene.rooms for p in r.polygon])
    lo, hi = rooms.min(0), rooms.max(0)
    pts: list[Array] = []
    have = 0
    for _ in range(50):
        cand = rng.uniform(lo, hi, (4 * samples, 2))
        X = np.column_stack([cand, np.full(len(cand), height)])
        vis = np.stack([renderer.sees(nc.name, X) & nc.in_view(X) for nc in net])
        keep = cand[vis.sum(0) >= 2]
        pts.append(keep)
        have += len(keep)
        if have >= samples:
            break
    truth = np.concatenate(pts)[:samples]
    if len(truth) < samples:
        raise InvalidInput("too few floor points are seen by two cameras in this scene")
    X = np.column_stack([truth, np.full(len(truth), height)])
    vis = np.stack([renderer.sees(nc.name, X) & nc.in_view(X) for nc in net])
    pixels = np.stack([nc.project(X) for nc in net])
    pixels = pixels + sigma_px * rng.standard_normal(pixels.shape)
    rmse, crb, n = _estimator_rmse(net, pixels, vis, truth, height, sigma_px)
    return LocalizationResult("localization", seed, n, sigma_px, rmse, crb, cameras_from="truth")


def localization_images(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    samples: int = 150,
    noise: SensorNoise | None = _DEFAULT_NOISE,
) -> LocalizationResult:
    """Return the estimators' RMSE on the robot marker detected in rendered images.

    The robot stands at `samples` random free floor poses seen by >= 2 cameras; each camera
    renders, the marker is detected (pixel and covariance from the detector); the estimators
    use the detector's covariances. `measured_sigma_px` is the RMS per-axis error of the
    detections against the marker's true image centre (ground truth used only for scoring);
    `sigma_px` the mean per-axis standard deviation the detector claimed.
    """
    scene = scene or default_scene()
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("localization-images needs a scene whose robot carries a marker")
    rng = np.random.default_rng(seed)
    renderer = Renderer(scene)
    pairs = _true_network(renderer)
    net = [nc for _, nc in pairs]
    marker = scene.robot.marker
    h = marker.height
    free = free_floor_grid(scene, 0.1, scene.robot.base_radius + 0.1)
    cand = free[rng.permutation(len(free))]
    X = np.column_stack([cand, np.full(len(cand), h)])
    sees = np.stack([renderer.sees(nc.name, X) & nc.in_view(X) for nc in net])
    cand = cand[sees.sum(0) >= 2][:samples]
    C, B = len(net), len(cand)
    pixels = np.zeros((C, B, 2))
    cov = np.tile(np.eye(2), (C, B, 1, 1))
    vis = np.zeros((C, B), bool)
    err: list[Array] = []
    cfg = MarkerDetectorConfig(colour=marker.colour)
    for j, (x, y) in enumerate(cand):
        # Yaw 0 and a centred marker (offset (0, 0) in the default robot) put it over (x, y).
        state = world_state(scene, 0.0, Pose2D(float(x), float(y), 0.0))
        for k, nc in enumerate(net):
            frame = renderer.render(nc.name, state, rng=rng, noise=noise)
            det = detect_marker(frame.image, cfg, background=renderer.empty(nc.name))
            if det is None:
                continue
            pixels[k, j], cov[k, j], vis[k, j] = det.pixel, det.cov, True
            if frame.marker_ellipse_pixel is not None:
                err.append(det.pixel - frame.marker_ellipse_pixel)
    two = vis.sum(0) >= 2
    truth = cand + np.array(marker.offset)
    claimed = float(np.sqrt(np.mean(cov[vis][:, [0, 1], [0, 1]])))
    rmse, crb, n = _estimator_rmse(
        net, pixels[:, two], vis[:, two], truth[two], h, claimed, cov[:, two]
    )
    e = np.array(err)
    measured = float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")
    return LocalizationResult(
        "localization-images", seed, n, claimed, rmse, crb, measured, cameras_from="truth"
    )
