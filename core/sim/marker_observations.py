"""What the ceiling cameras see of the robot's marker at the stops of a calibration drive.

Every camera sees the robot's marker at every stop (`observe_marker`): rendered and detected in
the image (`mode="images"`), or its true projection plus Gaussian noise of `sigma_px`
(`mode="projections"`, for studies of the pixel noise); `sigma_px` measured against the true
image centre is returned beside them (truth used only to score). A robot with a telescopic mast
raises it for the drive: its disc, 1.2 m up on the default robot, is seen with the top marker
(`MarkerObservations.mast`), and a marker above another gives each camera its tilt at every
stop. `robot_markers` is the calibration's layout of the robot's markers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.localization.detect import MarkerDetectorConfig, detect_marker
from core.sim.calibration_drive import Drive
from core.sim.motion import Pose2D, world_state
from core.sim.render import Renderer, SensorNoise
from core.sim.scene import Robot

Array = NDArray[np.float64]

_DEFAULT_NOISE = SensorNoise()


@dataclass(frozen=True)
class MarkerObservations:
    """Each camera's view of the marker at each stop: `pixels` (C, M, 2), `cov` (C, M, 2, 2)
    px^2 (the detector's, or sigma^2 I), `visible` (C, M), `areas` (C, M) the detected blobs'
    covered areas in pixels (NaN unseen or for projections), and `errors` the pixels minus
    the marker's true image centre (scoring only; `sigma_px` their RMS per axis)."""

    pixels: Array
    cov: Array
    visible: NDArray[np.bool_]
    errors: Array = field(repr=False)  # (K, 2) px, detections minus truth (scoring only)
    areas: Array | None = None
    mast: MarkerObservations | None = None

    def stacked(self) -> tuple[Array, Array, NDArray[np.bool_], Array | None]:
        """Return pixels (C, M, K, 2), covariances (C, M, K, 2, 2), visible (C, M, K) and
        areas (C, M, K) (None when unknown) of the K markers: the top one, then the mast's."""
        parts = [self] if self.mast is None else [self, self.mast]
        areas = None
        if all(p.areas is not None for p in parts):
            areas = np.stack([p.areas for p in parts], axis=2)  # type: ignore[misc]
        return (
            np.stack([p.pixels for p in parts], axis=2),
            np.stack([p.cov for p in parts], axis=2),
            np.stack([p.visible for p in parts], axis=2),
            areas,
        )

    @property
    def sigma_px(self) -> float:
        """RMS error per axis of the pixels against the marker's true image centre."""
        e = self.errors
        return float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")

    def joined(self, other: MarkerObservations) -> MarkerObservations:
        """Return these observations followed by `other`'s stops."""
        areas = None
        if self.areas is not None and other.areas is not None:
            areas = np.concatenate([self.areas, other.areas], axis=1)
        mast = None
        if self.mast is not None and other.mast is not None:
            mast = self.mast.joined(other.mast)
        return MarkerObservations(
            np.concatenate([self.pixels, other.pixels], axis=1),
            np.concatenate([self.cov, other.cov], axis=1),
            np.concatenate([self.visible, other.visible], axis=1),
            np.concatenate([self.errors, other.errors]),
            areas,
            mast,
        )

    def capped(self, visible: NDArray[np.bool_]) -> MarkerObservations:
        """Return these observations seen only where `visible` (C, M) also holds (every
        marker)."""
        mast = None if self.mast is None else self.mast.capped(visible)
        return MarkerObservations(
            self.pixels, self.cov, self.visible & visible, self.errors, self.areas, mast
        )


def observe_marker(
    renderer: Renderer,
    drive: Drive,
    rng: np.random.Generator,
    *,
    mode: str = "images",
    sigma_px: float = 0.5,
    noise: SensorNoise | None = _DEFAULT_NOISE,
    first: int = 0,
) -> MarkerObservations:
    """Return what every camera sees of the robot's marker (and of its mast marker, when it
    has one: `MarkerObservations.mast`) at the stops of `drive` from `first` on (module
    docstring, 3). Raises InvalidInput for an unknown mode or a robot without marker."""
    scene = renderer.scene
    if scene.robot is None or scene.robot.marker is None:
        raise InvalidInput("observing the marker needs a scene whose robot carries a marker")
    if mode not in ("images", "projections"):
        raise InvalidInput(f"unknown observation mode {mode!r}; use 'images' or 'projections'")
    if mode == "projections" and not sigma_px > 0:
        raise InvalidInput(f"sigma_px must be > 0 pixels, got {sigma_px}")
    markers = [scene.robot.marker]
    if scene.robot.mast_marker is not None:
        markers.append(scene.robot.mast_marker)
    cams = [renderer.camera(c.name) for c in scene.cameras]
    P = drive.true_poses[first:]
    times = drive.times[first:]
    C, M, K = len(cams), len(P), len(markers)
    c, s = np.cos(P[:, 2]), np.sin(P[:, 2])
    pixels = np.zeros((K, C, M, 2))
    cov = np.tile(np.eye(2), (K, C, M, 1, 1))
    vis = np.zeros((K, C, M), bool)
    areas = np.full((K, C, M), np.nan)
    errs: list[list[Array]] = [[] for _ in markers]
    if mode == "projections":
        for i, mk in enumerate(markers):
            off = mk.offset
            X = np.column_stack(
                [
                    P[:, 0] + c * off[0] - s * off[1],
                    P[:, 1] + s * off[0] + c * off[1],
                    np.full(M, mk.height),
                ]
            )
            for k, cam in enumerate(cams):
                vis[i, k] = renderer.sees(cam.name, X)
                e = sigma_px * rng.standard_normal((M, 2))
                pixels[i, k] = cam.project(X) + e
                errs[i].append(e[vis[i, k]])
        cov[:] = sigma_px**2 * np.eye(2)
        areas[:] = np.nan
    else:
        cfgs = [MarkerDetectorConfig(colour=mk.colour) for mk in markers]
        for j in range(M):
            state = world_state(scene, float(times[j]), Pose2D(*P[j]))
            for k, cam in enumerate(cams):
                frame = renderer.render(cam.name, state, rng=rng, noise=noise)
                truths = [frame.marker_ellipse_pixel, frame.mast_marker_ellipse_pixel]
                for i, cfg in enumerate(cfgs):
                    det = detect_marker(frame.image, cfg, background=renderer.empty(cam.name))
                    if det is None:
                        continue
                    pixels[i, k, j], cov[i, k, j], vis[i, k, j] = det.pixel, det.cov, True
                    areas[i, k, j] = det.area
                    truth = truths[i]
                    if truth is not None:
                        errs[i].append((det.pixel - truth)[None])
    out = None
    for i in reversed(range(K)):
        e = np.concatenate(errs[i]) if errs[i] else np.zeros((0, 2))
        out = MarkerObservations(pixels[i], cov[i], vis[i], e, areas[i], out)
    assert out is not None
    return out


def robot_markers(robot: Robot) -> tuple[Array, Array, Array]:
    """Return the heights (K,), offsets (K, 2) and radii (K,) of the robot's markers: its top
    marker, then its mast marker when it has one (the calibration's marker layout)."""
    ms = [m for m in (robot.marker, robot.mast_marker) if m is not None]
    return (
        np.array([m.height for m in ms]),
        np.array([m.offset for m in ms], dtype=np.float64).reshape(-1, 2),
        np.array([m.radius for m in ms]),
    )
