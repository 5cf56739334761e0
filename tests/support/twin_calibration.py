"""The `tracking` scene's network calibration, computed once by the project's own calibration
(core.sim.network_cameras.calibrated_cameras: each camera's chessboard
calibration, the robot's marker drive, the registration by the signposts) and stored as test
data, so a test that needs calibrated cameras does not redo a ~45 s drive.

What is stored is the calibration's estimate (K, distortion, pose and image size of every
camera it placed, and the names it rejected), never the twin's true cameras. The file records
a digest of the scene it was made for; `stored_calibrated_cameras` refuses it when the scene
has changed since. Regenerate after a change to the scene or to the calibration with

    .venv/bin/python -m tests.support.twin_calibration 17
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

from core.localization import NetworkCamera
from core.sim.network_cameras import CalibratedCameras, calibrated_cameras
from core.sim.scenarios import multi_target_tracking as ts
from core.sim.scene import Scene

DATA_DIR = Path(__file__).resolve().parents[1] / "data"
REGENERATE = ".venv/bin/python -m tests.support.twin_calibration {seed}"


def calibration_path(seed: int) -> Path:
    """Return the stored calibration file of the `tracking` scene for `seed`."""
    return DATA_DIR / f"tracking-calibration-seed{seed}.json"


def scene_digest(scene: Scene) -> str:
    """Return the SHA-256 of the scene's JSON: what a stored calibration was made for."""
    return hashlib.sha256(scene.model_dump_json().encode()).hexdigest()


def stored_calibrated_cameras(scene: Scene, seed: int) -> CalibratedCameras:
    """Return the stored calibration of `scene` for `seed`, exactly as calibrated_cameras
    returned it when it was stored (floats are written with repr, which round-trips)."""
    path = calibration_path(seed)
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: make it with {REGENERATE.format(seed=seed)}")
    data = json.loads(path.read_text())
    if data["scene_sha256"] != scene_digest(scene) or data["seed"] != seed:
        raise ValueError(
            f"{path} was made for another scene or seed: regenerate it with "
            f"{REGENERATE.format(seed=seed)}"
        )
    cameras = [
        NetworkCamera(
            K=c["K"],
            dist=c["dist"],
            R=c["R"],
            t=c["t"],
            image_size=tuple(c["image_size"]),
            name=c["name"],
        )
        for c in data["cameras"]
    ]
    return CalibratedCameras(cameras, list(data["index"]), tuple(data["rejected"]))


def store_calibrated_cameras(scene: Scene, seed: int) -> Path:
    """Run the network calibration of `scene` for `seed` and store it; return the file."""
    calibrated = calibrated_cameras(scene, seed)
    data = {
        "made_by": "core.sim.network_cameras.calibrated_cameras",
        "scene": "core.sim.scenarios.multi_target_tracking.tracking_scene()",
        "seed": seed,
        "scene_sha256": scene_digest(scene),
        "cameras": [
            {
                "name": c.name,
                "image_size": list(c.image_size) if c.image_size else None,
                "K": c.K.tolist(),
                "dist": c.dist.tolist(),
                "R": c.R.tolist(),
                "t": c.t.tolist(),
            }
            for c in calibrated.cameras
        ],
        "index": calibrated.index,
        "rejected": list(calibrated.rejected),
    }
    path = calibration_path(seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1) + "\n")
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("seeds", type=int, nargs="+", help="calibration seeds to store")
    args = parser.parse_args()
    for seed in args.seeds:
        print(store_calibrated_cameras(ts.tracking_scene(), seed))


if __name__ == "__main__":
    main()
