"""Quantize the person detector's network once to 8-bit integers: writes
core/localization/models/ssdlite_mobilenet_v2_coco_int8.onnx from the float model beside it (see
the README there).

The network's convolutions (the MobileNetV2 feature extractor and the box predictor: the nodes
named FeatureExtractor/... and BoxPredictor/...) are quantized statically, weights per output
channel (int8), activations per tensor (uint8), their ranges the minimum and maximum seen on
calibration tiles; the graph's own resize, box decoding and non-maximum suppression stay in
floating point. On a CPU with 8-bit dot-product instructions (AVX-512 VNNI, AVX-VNNI) onnxruntime
runs it about 1.8 times faster than the float model.

The calibration tiles are 300 x 300 crops of the sample images that Debian's opencv-doc package
ships in examples/data (people, buildings, rooms, objects; its video vtest.avi, the PETS 2009
footage the detector is measured on, is not used): two crops per image, one at full size and
one at half size, at places drawn from a seeded generator, so the result is reproducible.

Run outside the repository's environment (it needs the `onnx` package, which intspace does not
depend on), from the repository root:

    python3 -m venv /tmp/quantize && /tmp/quantize/bin/pip install onnx==1.23.2 \
        onnxruntime==1.32.0 opencv-python-headless==5.0.0.93 numpy==2.4.6
    (mkdir -p /tmp/opencv-doc && cd /tmp/opencv-doc && apt-get download opencv-doc \
        && dpkg-deb -x opencv-doc_*.deb x)
    /tmp/quantize/bin/python tools/quantize_ssdlite_int8.py \
        /tmp/opencv-doc/x/usr/share/doc/opencv-doc/examples/data
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import cv2
import numpy as np
import onnx
from onnxruntime.quantization import (
    CalibrationDataReader,
    CalibrationMethod,
    QuantFormat,
    QuantType,
    quantize_static,
)

MODELS = Path(__file__).resolve().parents[1] / "core" / "localization" / "models"
SOURCE = MODELS / "ssdlite_mobilenet_v2_coco.onnx"
TARGET = MODELS / "ssdlite_mobilenet_v2_coco_int8.onnx"
TILE = 300  # the model's input side
INPUT = "image_tensor:0"
SEED = 0


def calibration_tiles(folder: Path) -> list[np.ndarray]:
    """Return the RGB uint8 (1, 300, 300, 3) calibration tiles of the images in `folder`."""
    rng = np.random.default_rng(SEED)
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in {".jpg", ".png"})
    tiles = []
    for path in paths:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None or min(image.shape[:2]) < 120:
            continue
        for scale in (1.0, 0.5):
            img = image if scale == 1.0 else cv2.resize(image, None, fx=scale, fy=scale)
            if min(img.shape[:2]) < TILE:
                img = cv2.resize(img, (max(TILE, img.shape[1]), max(TILE, img.shape[0])))
            y = int(rng.integers(0, img.shape[0] - TILE + 1))
            x = int(rng.integers(0, img.shape[1] - TILE + 1))
            tiles.append(np.ascontiguousarray(img[y : y + TILE, x : x + TILE, ::-1][None]))
    return tiles


class _Tiles(CalibrationDataReader):
    def __init__(self, tiles: list[np.ndarray]) -> None:
        self._it = iter(tiles)

    def get_next(self) -> dict[str, np.ndarray] | None:
        tile = next(self._it, None)
        return None if tile is None else {INPUT: tile}


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit("usage: quantize_ssdlite_int8.py OPENCV_DOC_EXAMPLES_DATA_FOLDER")
    tiles = calibration_tiles(Path(sys.argv[1]))
    if len(tiles) < 100:
        raise SystemExit(f"only {len(tiles)} calibration tiles: is the folder opencv-doc's?")
    graph = onnx.load(str(SOURCE))
    network = [
        n.name for n in graph.graph.node if n.name.startswith(("FeatureExtractor", "BoxPredictor"))
    ]
    quantize_static(
        str(SOURCE),
        str(TARGET),
        _Tiles(tiles),
        quant_format=QuantFormat.QDQ,
        per_channel=True,
        activation_type=QuantType.QUInt8,
        weight_type=QuantType.QInt8,
        nodes_to_quantize=network,
        calibrate_method=CalibrationMethod.MinMax,
    )
    digest = hashlib.sha256(TARGET.read_bytes()).hexdigest()
    print(f"{len(tiles)} calibration tiles, {len(network)} nodes quantized")
    print(f"{TARGET.name} sha256 {digest}")


if __name__ == "__main__":
    main()
