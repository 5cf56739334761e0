"""Cut the converted SSDLite graph to its feature extractor and box predictor, in place.

    python tools/cut_ssdlite_onnx.py MODEL.onnx   (run by tools/convert_ssdlite_onnx.sh)

The model zoo's graph resizes every image to 300 x 300 and decodes and suppresses its boxes in
TensorFlow loops. What is kept is convolutions only, from the preprocessed image (RGB scaled to
[-1, 1], NCHW, any size) to the box encodings and class logits, plus each layer's class
predictor (its shape is the layer's grid): core.localization.ssd_people lays the anchors,
decodes and suppresses in numpy, and gives the network the camera's whole frame.
"""

from __future__ import annotations

import sys

import onnx  # in the converter's throwaway venv only
from onnx import TensorProto, helper

INPUT = "Preprocessor/sub:0"
OUTPUTS = ["concat:0", "concat_1:0"] + [
    f"BoxPredictor_{k}/ClassPredictor/BiasAdd:0" for k in range(6)
]


def main(path: str) -> None:
    model = onnx.load(path)
    graph = model.graph
    # The converter fixed these tensors' shapes for a 300 x 300 input: free them.
    keep = [v for v in graph.value_info if v.name not in OUTPUTS and v.name != INPUT]
    del graph.value_info[:]
    graph.value_info.extend(keep)
    graph.value_info.append(
        helper.make_tensor_value_info(INPUT, TensorProto.FLOAT, ["batch", 3, "height", "width"])
    )
    for name in OUTPUTS:
        graph.value_info.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, None))
    cut = onnx.utils.Extractor(model).extract_model([INPUT], OUTPUTS)
    onnx.save(cut, path)


if __name__ == "__main__":
    main(sys.argv[1])
