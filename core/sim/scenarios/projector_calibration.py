"""The `projector-calibration` scenario of the twin (spec 03).

14 commanded spots located on the floor by the ceiling cameras and T_world_base estimated by
the sparse LM (core.calibration.projector.calibrate_projector); its errors against the twin's
true projector (core.sim.projector). Each ceiling camera's frame of the home is rendered
(core.sim.render) with the laser's light added where the spot's image falls, when the camera
sees it (in view, not hidden by walls or furniture), and the spot is detected in it by
core.navigation.detect_laser_spot (core.sim.ceiling_spots); the spots are then located on the
floor by core.localization.locate_ml with the cameras' *calibrated* models, the marker network
calibration of the same seed (core.sim.network_cameras.calibrated_cameras), so their errors
include that calibration's.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.calibration.projector import calibrate_projector, mount_errors
from core.localization import NetworkCamera
from core.localization.ground import locate_ml
from core.navigation import occupancy_grid
from core.projector import PanTiltProjector
from core.sim.ceiling_spots import (
    CEILING_PIXEL_SIGMA,
    spots_in_images,
    spots_projected,
)
from core.sim.network_cameras import calibrated_cameras, frame_alignment, true_cameras
from core.sim.projector import nominal_projector, twin_projector
from core.sim.scene import Scene, default_scene
from core.sim.spot_following import PLAN_RESOLUTION

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ProjectorCalibrationResult:
    """Metrics of `projector-calibration`: `spots` commanded and located (by at least two
    cameras), their location error against the twin (`spot_error_rms_m`, per axis RMS), the
    mount's `position_error_m` and `rotation_error_deg` against the twin's true mount, the same
    after moving the estimate by the planar rigid motion that best aligns the calibrated
    cameras' centres with the twin's (`aligned_*`: the network calibration's own frame error
    removed, core.sim.network_cameras.frame_alignment; scoring only), the tilt
    offset's error (rad), the calibration's own standard deviations, its RMS floor
    residual (m), `cameras` the calibrated cameras used (their network calibration's
    output, `cameras_from`) and how the spots' pixels were found (`spots_from`). `model`
    (not in to_dict) is the calibrated projector."""

    scenario: str
    seed: int
    spots: int
    spot_error_rms_m: float
    position_error_m: float
    rotation_error_deg: float
    aligned_position_error_m: float
    aligned_rotation_error_deg: float
    tilt_offset_error_rad: float
    position_std_m: float
    rotation_std_deg: float
    rms_m: float
    cameras: tuple[str, ...]
    cameras_from: str
    spots_from: str
    model: PanTiltProjector = field(repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """Return the record as JSON-ready values (without the model)."""
        d = asdict(self)
        d.pop("model")
        return d


# The commanded spots: a grid over the living room, kept off the furniture (the plan says
# where it stands) and inside the projector's reach.
_CALIBRATION_GRID_X = (0.6, 1.3, 2.0, 2.7, 3.4, 4.0)
_CALIBRATION_GRID_Y = (0.8, 1.8, 2.8, 3.8, 4.7)


def projector_calibration(
    scene: Scene | None = None,
    seed: int = 0,
    *,
    cameras: list[NetworkCamera] | None = None,
    cameras_from: str = "marker network calibration (core.sim.network_cameras."
    "calibrated_cameras, rendered drive)",
    images: bool = True,
) -> ProjectorCalibrationResult:
    """Run the `projector-calibration` scenario (module docstring) and return its metrics.

    `cameras`: the calibrated ceiling cameras to locate the spots with (default: the scene's
    marker network calibration for `seed`, which renders a drive and takes a while).
    `images`: detect the spots in rendered images (default) or take their true projections
    plus pixel noise.
    """
    scene = scene or default_scene()
    truth = twin_projector(scene, seed)
    nominal = nominal_projector(scene)
    if cameras is None:
        cameras = list(calibrated_cameras(scene, seed).cameras)
    grid = occupancy_grid(scene, 0.1, PLAN_RESOLUTION)
    gx, gy = np.meshgrid(_CALIBRATION_GRID_X, _CALIBRATION_GRID_Y)
    targets = np.column_stack([gx.ravel(), gy.ravel()])
    ij = np.floor((targets - np.asarray(grid.origin)) / grid.resolution).astype(int)
    targets = targets[grid.free[ij[:, 1], ij[:, 0]]]
    q_cmd = nominal.aim(targets)
    spots = truth.spot(q_cmd)
    rng = np.random.default_rng([seed, 31])
    names = [c.name for c in cameras]
    if images:
        pixels, vis = spots_in_images(scene, names, spots, rng)
    else:
        pixels, vis = spots_projected(scene, names, spots, rng)
    located = locate_ml(
        cameras,
        np.nan_to_num(pixels),
        0.0,
        visible=vis,
        pixel_sigma=CEILING_PIXEL_SIGMA,
        min_cameras=2,
    )
    ok = located.valid
    calib = calibrate_projector(nominal, q_cmd[ok], located.xy[ok], estimate_tilt_offset=True)
    pos_err, rot_err = mount_errors(calib.T_world_base, truth.T_world_base)
    T2 = frame_alignment(cameras, true_cameras(scene, names))
    T4 = np.eye(4)
    T4[:2, :2], T4[:2, 3] = T2[:2, :2], T2[:2, 2]
    al_pos, al_rot = mount_errors(T4 @ calib.T_world_base, truth.T_world_base)
    spot_err = located.xy[ok] - spots[ok]
    return ProjectorCalibrationResult(
        scenario="projector-calibration",
        seed=seed,
        spots=int(ok.sum()),
        spot_error_rms_m=float(np.sqrt(np.mean(spot_err**2))),
        position_error_m=pos_err,
        rotation_error_deg=rot_err,
        aligned_position_error_m=al_pos,
        aligned_rotation_error_deg=al_rot,
        tilt_offset_error_rad=float(calib.tilt_offset - (truth.theta[1] - nominal.theta[1])),
        position_std_m=float(np.linalg.norm(calib.position_std)),
        rotation_std_deg=calib.rotation_std_deg,
        rms_m=calib.rms,
        cameras=tuple(names),
        cameras_from=cameras_from,
        spots_from="detected in rendered images" if images else "projected with pixel noise",
        model=calib.model,
    )
