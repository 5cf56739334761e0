"""Zhang's published calibration data (Zhang 1998, `../shared/data/zhang1998`: the model plane's
256 corners and five images of it) and the values his paper prints for it, for the calibration
tests and bench."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from core.calibration import CameraCalibration

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "zhang1998"
PUBLISHED = {  # name: printed value as text (the number of digits is the comparison precision)
    "alpha": "832.5",
    "gamma": "0.204494",
    "beta": "832.53",
    "u0": "303.959",
    "v0": "206.585",
    "k1": "-0.228601",
    "k2": "0.190353",
}
PUBLISHED_R1 = [
    ["0.992759", "-0.026319", "0.117201"],
    ["0.0139247", "0.994339", "0.105341"],
    ["-0.11931", "-0.102947", "0.987505"],
]
PUBLISHED_T1 = ["-3.84019", "3.65164", "12.791"]


def decimals(text: str) -> int:
    """Return the number of decimals a printed value has (its comparison precision)."""
    return len(text.split(".")[1]) if "." in text else 0


def read_zhang() -> tuple[np.ndarray, list[np.ndarray]]:
    """Return the model plane's points (256, 2) and the five images' points (256, 2) each."""
    model = np.loadtxt(DATA / "Model.txt").reshape(-1, 2)
    images = [np.loadtxt(DATA / f"data{i}.txt").reshape(-1, 2) for i in range(1, 6)]
    return model, images


def zhang_values(c: CameraCalibration) -> dict[str, float]:
    """Return a calibration's values under the names Zhang prints them with."""
    return {
        "alpha": c.K[0, 0],
        "gamma": c.K[0, 1],
        "beta": c.K[1, 1],
        "u0": c.K[0, 2],
        "v0": c.K[1, 2],
        "k1": c.dist[0],
        "k2": c.dist[1],
    }
