"""Named, seeded scenarios of the digital twin, each returning its metrics as a typed record.

* `network-calibration`: the robot's marker is driven over a programme of floor poses, every
  camera renders it, the marker is detected in the images and the network calibrated from
  the detections (core.calibration.network, marker kind); errors against the twin's cameras.
* `localization`: floor points seen by >= 2 of the twin's true cameras, pixels = projections
  plus Gaussian noise; the RMSE of the four ground estimators against the Cramer-Rao bound.
* `localization-images`: the same estimators on the marker detected in rendered images, with
  the measured pixel noise of the detector beside the errors.

`run_scenario(name, scene=None, seed=0)` runs one; `SCENARIOS` lists them. Every record has
`to_dict()` giving plain JSON-ready values.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.calibration.network import calibrate_network_marker
from core.errors import InvalidInput
from core.geometry.rotations import matrix_to_rotvec
from core.localization import (
    NetworkCamera,
    cramer_rao_bound,
    locate_ml,
    locate_monocular,
    triangulate_linear,
    triangulate_on_plane,
)
from core.localization.detect import MarkerDetectorConfig, detect_marker
from core.sim.motion import Pose2D, world_state
from core.sim.render import CameraModel, Renderer, SensorNoise
from core.sim.scene import Scene, default_scene

Array = NDArray[np.float64]

_DEFAULT_NOISE = SensorNoise()


# --------------------------------------------------------------------------------------------
# Records


@dataclass(frozen=True)
class CameraCalibrationError:
    """One camera's calibration against the twin: focal error in percent of the true
    (fx + fy) / 2 (signed), optical-centre position error metres, orientation error degrees
    (angle of R_est R_true^T), poses seen, reprojection RMS pixels."""

    name: str
    focal_error_pct: float
    position_error_m: float
    rotation_error_deg: float
    poses_seen: int
    rms_px: float


@dataclass(frozen=True)
class RejectedCameraReport:
    """A camera the calibration left out, with the reason."""

    name: str
    reason: str
    poses_seen: int


@dataclass(frozen=True)
class NetworkCalibrationResult:
    """Metrics of `network-calibration`: per-camera errors, rejected cameras, the number of
    programme poses and detections, the target kind used and how the targets were treated."""

    scenario: str
    seed: int
    target_kind: str
    poses: int
    detections: int
    placement_sigma_m: float
    distortion: str
    cameras: tuple[CameraCalibrationError, ...]
    rejected: tuple[RejectedCameraReport, ...]

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


@dataclass(frozen=True)
class LocalizationResult:
    """Metrics of `localization` / `localization-images`: samples located, pixel noise sigma
    (given, or measured from the detections), RMSE metres per estimator (mono, linear,
    constrained, ml) and the Cramer-Rao root mean trace for the cameras ML used."""

    scenario: str
    seed: int
    samples: int
    sigma_px: float
    rmse_m: dict[str, float]
    crb_rmse_m: float
    measured_sigma_px: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values."""
        return asdict(self)


ScenarioResult = NetworkCalibrationResult | LocalizationResult


# --------------------------------------------------------------------------------------------
# Helpers


def _free_floor_grid(scene: Scene, spacing: float, clearance: float) -> Array:
    """Return floor points (N, 2) on a grid of `spacing` metres inside the rooms, at least
    `clearance` metres from every wall and furniture footprint (robot radius plus margin)."""
    rooms = np.array([p for r in scene.rooms for p in r.polygon])
    lo, hi = rooms.min(0), rooms.max(0)
    gx = np.arange(lo[0] + spacing / 2, hi[0], spacing)
    gy = np.arange(lo[1] + spacing / 2, hi[1], spacing)
    P = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
    ok = np.zeros(len(P), bool)
    for room in scene.rooms:
        ok |= _inside(P, np.array(room.polygon))
    for w in scene.walls:
        a, b = np.array(w.start), np.array(w.end)
        d = b - a
        s = np.clip((P - a) @ d / (d @ d), 0, 1)
        ok &= np.linalg.norm(P - (a + s[:, None] * d), axis=1) > clearance + w.thickness / 2
    for f in scene.furniture:
        c, s_ = math.cos(f.yaw), math.sin(f.yaw)
        q = (P - np.array(f.centre)) @ np.array([[c, -s_], [s_, c]])
        half = np.array(f.size[:2]) / 2 + clearance
        ok &= ~np.all(np.abs(q) < half, axis=1)
    return P[ok]


def _inside(P: Array, poly: Array) -> NDArray[np.bool_]:
    """Return whether points (N, 2) lie inside a simple polygon (V, 2) (even-odd rule)."""
    x, y = P[:, 0:1], P[:, 1:2]
    a, b = poly, np.roll(poly, -1, axis=0)
    cross = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return np.asarray(np.sum(cross & (x < xi), axis=1) % 2 == 1)


def _rotation_angle_deg(Ra: Array, Rb: Array) -> float:
    return float(np.degrees(np.linalg.norm(matrix_to_rotvec(Ra @ Rb.T))))


def _true_network(renderer: Renderer) -> list[tuple[CameraModel, NetworkCamera]]:
    out = []
    for spec in renderer.scene.cameras:
        m = renderer.camera(spec.name)
        nc = NetworkCamera.from_pose(m.K, m.dist, m.T_world_camera, (m.width, m.height), m.name)
        out.append((m, nc))
    return out


# --------------------------------------------------------------------------------------------
# Scenarios


def network_calibration(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    spacing: float = 0.3,
    placement_sigma: float = 0.002,
    noise: SensorNoise | None = _DEFAULT_NOISE,
    min_poses: int = 8,
    camera_poses: dict[str, int] | None = None,
    refine_targets: bool = True,
) -> NetworkCalibrationResult:
    """Return the metrics of calibrating the scene's cameras by driving the robot's marker.

    Programme: a grid of floor poses `spacing` metres apart over the free floor (random yaw),
    stop-and-go; the robot stops within `placement_sigma` metres (per axis, Gaussian) of each
    scripted pose, and the scripted pose is what the calibration is told, with that standard
    deviation as its prior. Every camera renders every stop; the marker is detected (no ground
    truth); the principal points and the lens distortion are taken from the scene as the
    "given" and "known" values the marker kind requires. `camera_poses` optionally caps how many
    stops a named camera gets to see (for robustness checks). Errors are against the scene.
    """
    scene = scene or default_scene()
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("network-calibration needs a scene whose robot carries a marker")
    if not scene.cameras:
        raise InvalidInput("network-calibration needs a scene with cameras")
    rng = np.random.default_rng(seed)
    renderer = Renderer(scene)
    marker = scene.robot.marker
    grid = _free_floor_grid(scene, spacing, scene.robot.base_radius + 0.05)
    grid = grid + rng.uniform(-0.1, 0.1, grid.shape) * spacing
    yaw = rng.uniform(-math.pi, math.pi, len(grid))
    truth = grid + placement_sigma * rng.standard_normal(grid.shape)
    # The marker's floor position for a robot pose (x, y, yaw): its offset turned by yaw.
    off = np.array(marker.offset)
    c, s = np.cos(yaw), np.sin(yaw)
    rot_off = np.stack([c * off[0] - s * off[1], s * off[0] + c * off[1]], 1)
    cams = [renderer.camera(cs.name) for cs in scene.cameras]
    C, M = len(cams), len(grid)
    pixels = np.zeros((C, M, 2))
    cov = np.tile(np.eye(2), (C, M, 1, 1))
    seen = np.zeros((C, M), bool)
    cfg = MarkerDetectorConfig(colour=marker.colour)
    for j in range(M):
        state = world_state(scene, 0.0, Pose2D(float(truth[j, 0]), float(truth[j, 1]), yaw[j]))
        for k, cam in enumerate(cams):
            frame = renderer.render(cam.name, state, rng=rng, noise=noise)
            det = detect_marker(frame.image, cfg)
            if det is not None:
                pixels[k, j], cov[k, j], seen[k, j] = det.pixel, det.cov, True
    for name, cap in (camera_poses or {}).items():
        k = [cm.name for cm in cams].index(name)
        idx = np.flatnonzero(seen[k])
        seen[k, idx[cap:]] = False
    net = calibrate_network_marker(
        [cm.name for cm in cams],
        [cm.K[:2, 2] for cm in cams],
        [cm.dist for cm in cams],
        pixels,
        seen,
        grid + rot_off,
        marker.height,
        pixel_cov=cov,
        target_sigma=placement_sigma if refine_targets else 0.0,
        min_poses=min_poses,
    )
    errors = []
    for cal in net.cameras:
        true = next(cm for cm in cams if cm.name == cal.name)
        f_true = 0.5 * (true.K[0, 0] + true.K[1, 1])
        errors.append(
            CameraCalibrationError(
                name=cal.name,
                focal_error_pct=float(100 * (cal.focal - f_true) / f_true),
                position_error_m=float(np.linalg.norm(cal.position - true.position)),
                rotation_error_deg=_rotation_angle_deg(cal.R, true.R_camera_world),
                poses_seen=cal.poses_seen,
                rms_px=cal.rms,
            )
        )
    return NetworkCalibrationResult(
        scenario="network-calibration",
        seed=seed,
        target_kind="marker",
        poses=M,
        detections=int(seen.sum()),
        placement_sigma_m=placement_sigma,
        distortion="known (the scene's true coefficients), held fixed",
        cameras=tuple(errors),
        rejected=tuple(RejectedCameraReport(r.name, r.reason, r.poses_seen) for r in net.rejected),
    )


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
    return LocalizationResult("localization", seed, n, sigma_px, rmse, crb)


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
    free = _free_floor_grid(scene, 0.1, scene.robot.base_radius + 0.1)
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
            det = detect_marker(frame.image, cfg)
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
    return LocalizationResult("localization-images", seed, n, claimed, rmse, crb, measured)


SCENARIOS: dict[str, Callable[..., ScenarioResult]] = {
    "network-calibration": network_calibration,
    "localization": localization,
    "localization-images": localization_images,
}

DESCRIPTIONS: dict[str, str] = {
    "network-calibration": "calibrate every ceiling camera by driving the robot's marker",
    "localization": "ground estimators vs the Cramer-Rao bound on noisy true projections",
    "localization-images": "ground estimators on the robot marker detected in rendered images",
}


def run_scenario(name: str, scene: Scene | None = None, seed: int = 0) -> ScenarioResult:
    """Return the metrics of the scenario called `name` on `scene` (default home) with `seed`.

    Raises InvalidInput naming the known scenarios when `name` is not one of them.
    """
    fn = SCENARIOS.get(name)
    if fn is None:
        raise InvalidInput(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")
    return fn(scene, seed)
