"""The ceiling cameras as the tracker knows them (`NetworkCamera`): the twin's true ones, for
simulating what they see and for scoring only (`true_cameras`), and the ones the home's marker
network calibration estimates (`calibrated_cameras`, `CalibratedCameras`); the calibrated home
frame's rigid error against the twin's (`frame_alignment`, `frame_error`: scoring only), and
how many cameras see a body's point (`cameras_seeing`, `seen_by_any`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from core.localization import NetworkCamera, Occluders, line_of_sight
from core.sim.render import camera_model
from core.sim.scene import Scene

Array = NDArray[np.float64]


def true_cameras(scene: Scene, names: Sequence[str] | None = None) -> list[NetworkCamera]:
    """Return the twin's true cameras (the scene's, or those called `names` in that order), for
    simulating what they see and for scoring only: the true lenses form the images (physics,
    not an estimate)."""
    specs = scene.cameras if names is None else [scene.camera(n) for n in names]
    out = []
    for spec in specs:
        m = camera_model(spec)
        out.append(
            NetworkCamera.from_pose(m.K, m.dist, m.T_world_camera, (m.width, m.height), m.name)
        )
    return out


@dataclass(frozen=True)
class CalibratedCameras:
    """The cameras as the home knows them after its network calibration: `cameras` (the
    calibrated ones), `index` (each one's index in the scene's cameras) and `rejected` (names
    of the cameras the calibration could not place, which the tracker never hears from)."""

    cameras: list[NetworkCamera]
    index: list[int]
    rejected: tuple[str, ...]

    def first(self, n: int) -> CalibratedCameras:
        """Return the calibrated cameras among the scene's first `n`."""
        keep = [k for k, i in enumerate(self.index) if i < n]
        return CalibratedCameras(
            [self.cameras[k] for k in keep], [self.index[k] for k in keep], self.rejected
        )


_CALIBRATION_CACHE: dict[tuple[str, int], CalibratedCameras] = {}


def calibrated_cameras(scene: Scene, seed: int) -> CalibratedCameras:
    """Return the scene's cameras as its marker network calibration estimates them: each
    camera's own chessboard calibration, then the robot's drive with its odometry
    (core.sim.network_drive.drive_marker_calibration, rendered images), registered to the world
    by its tour of the signposts (core.sim.network_registration). Nothing of the twin's
    true cameras reaches the tracker. Cached per (scene, seed): the drive takes seconds."""
    key = (scene.model_dump_json(), seed)
    hit = _CALIBRATION_CACHE.get(key)
    if hit is not None:
        return hit
    # Imported here: the drive pulls the calibration stack, which the points-only helpers of
    # this module do not need.
    from core.sim.network_drive import drive_marker_calibration
    from core.sim.network_registration import can_register, register_network

    net = drive_marker_calibration(scene, seed).calibration
    if can_register(scene):
        net, _ = register_network(net, scene, seed)
    names = [c.name for c in scene.cameras]
    # A camera's resolution is what its owner knows of it without any calibration.
    sizes = {c.name: (camera_model(c).width, camera_model(c).height) for c in scene.cameras}
    cams = [
        NetworkCamera.from_pose(c.K, c.dist, c.T_world_camera, sizes[c.name], c.name)
        for c in net.cameras
    ]
    result = CalibratedCameras(
        cams, [names.index(c.name) for c in net.cameras], tuple(r.name for r in net.rejected)
    )
    _CALIBRATION_CACHE[key] = result
    return result


def frame_alignment(calibrated: list[NetworkCamera], truth: list[NetworkCamera]) -> Array:
    """Return the 3x3 planar rigid transform (rotation about the vertical, then translation)
    taking the calibrated home frame to the twin's, fitted by least squares to the cameras'
    centres (Kabsch in the plane). The calibration fixes its frame by the robot's start pose
    and its first straight leg, so that frame carries a small rigid error of its own (the
    calibration's gauge, inside its Cramer-Rao bound); scoring with and without this transform
    separates the tracker's error from the frame's. For scoring only: it reads the truth."""
    a = np.array([c.center[:2] for c in calibrated])
    b = np.array([c.center[:2] for c in truth])
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    r = (u @ vt).T
    if np.linalg.det(r) < 0:
        vt[-1] *= -1
        r = (u @ vt).T
    T = np.eye(3)
    T[:2, :2] = r
    T[:2, 2] = cb - r @ ca
    return T


def frame_error(calibrated: list[NetworkCamera], T: Array) -> tuple[float, float]:
    """Return the calibrated frame's error: the largest displacement (m) T makes at a
    calibrated camera's centre, and its rotation (deg)."""
    a = np.array([c.center[:2] for c in calibrated])
    moved = a @ T[:2, :2].T + T[:2, 2]
    shift = float(np.max(np.linalg.norm(moved - a, axis=1)))
    return shift, float(np.degrees(abs(np.arctan2(T[1, 0], T[0, 0]))))


def seen_by_any(
    cameras: list[NetworkCamera],
    xy: Array,
    height: float | Array,
    occluders: Occluders | None = None,
) -> NDArray[np.bool_]:
    """Return (N, B) whether any camera sees each body's point at `height`."""
    return cameras_seeing(cameras, xy, height, occluders) > 0


def cameras_seeing(
    cameras: list[NetworkCamera],
    xy: Array,
    height: float | Array,
    occluders: Occluders | None = None,
) -> NDArray[np.int64]:
    """Return (N, B) how many cameras see each body's point at `height` (one value, or one
    per body): in their view and, given occluders, with a clear line of sight."""
    n, b = xy.shape[:2]
    h = np.broadcast_to(np.asarray(height, dtype=np.float64), (b,))
    pts = np.concatenate([xy, np.broadcast_to(h[None, :, None], (n, b, 1))], axis=2)
    pts = pts.reshape(-1, 3)
    count = np.zeros(n * b, dtype=np.int64)
    for cam in cameras:
        ok = cam.in_view(pts)
        if occluders is not None and ok.any():
            ok[ok] = line_of_sight(cam.center[None], pts[ok], occluders)[0]
        count += ok
    return count.reshape(n, b)
