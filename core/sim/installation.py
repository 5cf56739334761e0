"""The twin's installed calibration: the home's cameras as their network calibration placed them.

A home is calibrated once, when its cameras are installed: each camera is shown a chessboard,
then the robot drives its marker past them (core.sim.network_drive.drive_marker_calibration)
and tours the signposts, which register the network to the world
(core.sim.network_registration). The service's twin starts from that result, never from the
twin's true cameras. The default home's calibration is shipped with the package
(`data/installed_calibration.json`, made by `write_installed_calibration` from the drive with
`INSTALL_SEED`), so the service does not spend the drive's seconds at every start; any other
home is calibrated when first asked.

The file names the scene it belongs to by a fingerprint of what the calibration sees (cameras,
robot, walls, furniture); a home that differs gets its own drive.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from core.localization import NetworkCamera
from core.sim.render import camera_model
from core.sim.scene import Scene

Array = NDArray[np.float64]

INSTALL_SEED = 0
DATA_FILE = Path(__file__).parent / "data" / "installed_calibration.json"


@dataclass(frozen=True)
class InstalledCamera:
    """One camera as calibrated: `K` (3, 3), `dist` (5,), `T_world_camera` (4, 4), and the
    calibration's standard deviations of focal (px), translation t_camera_world (m) and
    rotation (deg)."""

    name: str
    K: Array
    dist: Array
    T_world_camera: Array
    focal_std_px: float
    translation_std_m: float
    rotation_std_deg: float


@dataclass(frozen=True)
class InstalledCalibration:
    """The home's calibration: its cameras, those the drive could not place (name -> reason),
    the drive's seed and length (s), and where it came from ("shipped" or "computed")."""

    cameras: tuple[InstalledCamera, ...]
    rejected: dict[str, str]
    seed: int
    drive_s: float
    source: str


def scene_fingerprint(scene: Scene) -> str:
    """Return a short hash of what a network calibration of `scene` depends on: everything but
    the people who walk through it."""
    data = scene.model_dump(mode="json", exclude={"people"})
    text = json.dumps(data, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def calibrate_installation(scene: Scene, seed: int = INSTALL_SEED) -> InstalledCalibration:
    """Return the network calibration of `scene`'s cameras by the robot's marker drive,
    registered to the world by its tour of the signposts where the home has them
    (core.sim.network_registration)."""
    # The whole calibration stack, and the signpost tour's head camera.
    from core.sim.network_drive import drive_marker_calibration
    from core.sim.network_registration import can_register, register_network

    md = drive_marker_calibration(scene, seed)
    net = md.calibration
    if can_register(scene):
        net, _ = register_network(net, scene, seed)
    cams = []
    for c in net.cameras:
        std = dict(zip(c.parameter_names, np.asarray(c.std, dtype=np.float64), strict=False))

        def norm(*names: str, std: dict[str, float] = std) -> float:
            return float(np.sqrt(sum(std.get(n, 0.0) ** 2 for n in names)))

        cams.append(
            InstalledCamera(
                c.name,
                np.asarray(c.K, dtype=np.float64),
                np.asarray(c.dist, dtype=np.float64),
                np.asarray(c.T_world_camera, dtype=np.float64),
                norm("f") if "f" in std else norm("fx"),
                norm("tx", "ty", "tz"),
                float(np.degrees(norm("rx", "ry", "rz"))),
            )
        )
    rejected = {r.name: r.reason for r in net.rejected}
    return InstalledCalibration(tuple(cams), rejected, seed, md.drive.duration_s, "computed")


def _to_json(cal: InstalledCalibration, fingerprint: str) -> dict[str, object]:
    return {
        "scene_fingerprint": fingerprint,
        "seed": cal.seed,
        "drive_s": cal.drive_s,
        "rejected": cal.rejected,
        "cameras": [
            {
                "name": c.name,
                "K": c.K.tolist(),
                "dist": c.dist.tolist(),
                "T_world_camera": c.T_world_camera.tolist(),
                "focal_std_px": c.focal_std_px,
                "translation_std_m": c.translation_std_m,
                "rotation_std_deg": c.rotation_std_deg,
            }
            for c in cal.cameras
        ],
    }


def _from_json(data: dict, source: str) -> InstalledCalibration:
    cams = tuple(
        InstalledCamera(
            c["name"],
            np.array(c["K"], dtype=np.float64),
            np.array(c["dist"], dtype=np.float64),
            np.array(c["T_world_camera"], dtype=np.float64),
            float(c["focal_std_px"]),
            float(c["translation_std_m"]),
            float(c["rotation_std_deg"]),
        )
        for c in data["cameras"]
    )
    return InstalledCalibration(
        cams, dict(data["rejected"]), int(data["seed"]), float(data["drive_s"]), source
    )


def write_installed_calibration(scene: Scene, path: Path = DATA_FILE) -> InstalledCalibration:
    """Calibrate `scene` (INSTALL_SEED) and write the result to `path`; return it."""
    cal = calibrate_installation(scene)
    path.write_text(json.dumps(_to_json(cal, scene_fingerprint(scene)), indent=1) + "\n")
    return cal


def installed_calibration(scene: Scene, path: Path = DATA_FILE) -> InstalledCalibration:
    """Return `scene`'s installed calibration: the shipped one when it belongs to this scene,
    else a new drive (seconds)."""
    if path.is_file():
        data = json.loads(path.read_text())
        if data.get("scene_fingerprint") == scene_fingerprint(scene):
            return _from_json(data, "shipped")
    return calibrate_installation(scene)


_INSTALLED: dict[str, list[NetworkCamera]] = {}


def installed_cameras(scene: Scene) -> list[NetworkCamera]:
    """Return the scene's ceiling cameras as its installed network calibration has them
    (core.sim.installation: shipped for the default home, else a calibration drive, whose
    result is kept for the process's life)."""
    key = scene_fingerprint(scene)
    hit = _INSTALLED.get(key)
    if hit is None:
        cal = installed_calibration(scene)
        # A camera's resolution is what its owner knows of it without any calibration.
        sizes = {c.name: (camera_model(c).width, camera_model(c).height) for c in scene.cameras}
        hit = [
            NetworkCamera.from_pose(c.K, c.dist, c.T_world_camera, sizes[c.name], c.name)
            for c in cal.cameras
        ]
        _INSTALLED[key] = hit
    return list(hit)
