"""Camera calibration interchange: OpenCV FileStorage YAML and JSON, ROS camera_info YAML.

Functions turn a `CalibrationRecord` into text and text back into a record; reading and writing
files is the caller's business. What is written can be read by cv2.FileStorage (the YAML and
JSON forms) and by ROS camera_calibration_parsers (the camera_info form); what they write can be
read here. Malformed text raises InvalidInput with the reason.

OpenCV keys: image_width, image_height, camera_matrix, distortion_coefficients (the names used by
OpenCV's calibration sample; cameraMatrix, dist_coeffs / distCoeffs and cameraResolution, used by
other OpenCV tools, are read too), optional avg_reprojection_error and camera_name.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from core._validate import as_matrix
from core.errors import InvalidInput

Array = NDArray[np.float64]

# Lengths of OpenCV's distortion vector: (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]]).
_DIST_LENGTHS = (4, 5, 8, 12, 14)
_ROS_MODELS = {5: "plumb_bob", 8: "rational_polynomial"}

_K_KEYS = ("camera_matrix", "cameraMatrix")
_DIST_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs")


@dataclass(frozen=True)
class CalibrationRecord:
    """The intrinsic calibration of one camera as exchanged with other tools.

    K: (3, 3) camera matrix, px. dist: OpenCV distortion coefficients (k1, k2, p1, p2[, k3[, ...]]),
    4, 5, 8, 12 or 14 values, dimensionless. image_size: (width, height) px. rms: reprojection
    RMS of the calibration, px, if known. camera_name: free text. rectification: (3, 3) and
    projection: (3, 4), ROS's R and P; None means identity and [K | 0], a monocular camera.
    """

    K: Array
    dist: Array
    image_size: tuple[int, int]
    rms: float | None = None
    camera_name: str = "camera"
    rectification: Array | None = field(default=None)
    projection: Array | None = field(default=None)

    def __post_init__(self) -> None:
        K = as_matrix(self.K, (3, 3), "K")
        if K[0, 0] <= 0.0 or K[1, 1] <= 0.0 or K[2, 2] != 1.0 or np.any(K[1:, 0] != 0.0):
            raise InvalidInput(
                f"K must be upper triangular with fx, fy > 0 and K[2, 2] = 1, got {K.tolist()}"
            )
        d = np.asarray(self.dist, dtype=np.float64).ravel()
        if d.size not in _DIST_LENGTHS or not np.all(np.isfinite(d)):
            raise InvalidInput(
                f"dist must hold 4, 5, 8, 12 or 14 finite coefficients, got {d.size}: {d.tolist()}"
            )
        try:
            w, h = (int(v) for v in self.image_size)
        except (TypeError, ValueError):
            raise InvalidInput(
                f"image_size must be (width, height), got {self.image_size!r}"
            ) from None
        if w <= 0 or h <= 0:
            raise InvalidInput(f"image_size must be positive (width, height), got {(w, h)}")
        rms = None if self.rms is None else _float(self.rms, "rms")
        if rms is not None and not (math.isfinite(rms) and rms >= 0.0):
            raise InvalidInput(f"rms must be a finite non-negative number, got {self.rms!r}")
        R = None if self.rectification is None else as_matrix(self.rectification, (3, 3), "R")
        P = None if self.projection is None else as_matrix(self.projection, (3, 4), "P")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", d)
        object.__setattr__(self, "image_size", (w, h))
        object.__setattr__(self, "rms", rms)
        object.__setattr__(self, "camera_name", str(self.camera_name))
        object.__setattr__(self, "rectification", R)
        object.__setattr__(self, "projection", P)

    @property
    def R(self) -> Array:
        """The (3, 3) rectification matrix (identity for a monocular camera)."""
        return np.eye(3) if self.rectification is None else self.rectification

    @property
    def P(self) -> Array:
        """The (3, 4) projection matrix of the rectified image ([K | 0] for a monocular camera)."""
        return np.hstack([self.K, np.zeros((3, 1))]) if self.projection is None else self.projection


# --- OpenCV FileStorage YAML -------------------------------------------------------------------


def to_opencv_yaml(record: CalibrationRecord) -> str:
    """Return the record as OpenCV FileStorage YAML text (readable by cv2.FileStorage)."""
    lines = [
        "%YAML:1.0",
        "---",
        f"camera_name: {json.dumps(record.camera_name, ensure_ascii=False)}",
        f"image_width: {record.image_size[0]}",
        f"image_height: {record.image_size[1]}",
        *_yaml_opencv_matrix("camera_matrix", record.K),
        *_yaml_opencv_matrix("distortion_coefficients", record.dist.reshape(-1, 1)),
    ]
    if record.rms is not None:
        lines.append(f"avg_reprojection_error: {_num(record.rms)}")
    return "\n".join(lines) + "\n"


def from_opencv_yaml(text: str) -> CalibrationRecord:
    """Return the record in OpenCV FileStorage YAML text (as cv2.FileStorage writes it).

    Raises InvalidInput when the text is not such YAML or lacks the camera matrix, distortion
    coefficients or image size.
    """
    body = _text(text)
    stripped = body.lstrip()
    if stripped.startswith("%YAML"):
        # OpenCV writes the directive as "%YAML:1.0", which YAML parsers reject; drop that line.
        body = stripped.split("\n", 1)[1] if "\n" in stripped else ""
    try:
        doc = yaml.load(body, Loader=_OpenCVLoader)  # a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise InvalidInput(f"not valid OpenCV YAML: {exc}") from None
    return _record_from_opencv(doc, "OpenCV YAML")


# --- OpenCV FileStorage JSON -------------------------------------------------------------------


def to_opencv_json(record: CalibrationRecord) -> str:
    """Return the record as OpenCV FileStorage JSON text (readable by cv2.FileStorage)."""
    doc: dict[str, Any] = {
        "camera_name": record.camera_name,
        "image_width": record.image_size[0],
        "image_height": record.image_size[1],
        "camera_matrix": _json_opencv_matrix(record.K),
        "distortion_coefficients": _json_opencv_matrix(record.dist.reshape(-1, 1)),
    }
    if record.rms is not None:
        doc["avg_reprojection_error"] = record.rms
    return json.dumps(doc, indent=4) + "\n"


def from_opencv_json(text: str) -> CalibrationRecord:
    """Return the record in OpenCV FileStorage JSON text. Raises InvalidInput when malformed."""
    try:
        doc = json.loads(_text(text))
    except json.JSONDecodeError as exc:
        raise InvalidInput(f"not valid JSON: {exc}") from None
    return _record_from_opencv(doc, "OpenCV JSON")


# --- ROS camera_info YAML ----------------------------------------------------------------------


def to_ros_yaml(record: CalibrationRecord) -> str:
    """Return the record as ROS camera_info YAML (camera_calibration_parsers' format).

    Distortion model plumb_bob for 4 or 5 coefficients (4 are padded with k3 = 0),
    rational_polynomial for 8. Raises InvalidInput for 12 or 14 coefficients, which ROS's pinhole
    models cannot hold.
    """
    d = record.dist
    if d.size == 4:
        d = np.append(d, 0.0)
    if d.size not in _ROS_MODELS:
        raise InvalidInput(
            f"ROS camera_info has no distortion model for {d.size} coefficients "
            "(plumb_bob takes 5, rational_polynomial 8)"
        )
    lines = [
        f"image_width: {record.image_size[0]}",
        f"image_height: {record.image_size[1]}",
        f"camera_name: {json.dumps(record.camera_name, ensure_ascii=False)}",
        *_yaml_ros_matrix("camera_matrix", record.K),
        f"distortion_model: {_ROS_MODELS[d.size]}",
        *_yaml_ros_matrix("distortion_coefficients", d.reshape(1, -1)),
        *_yaml_ros_matrix("rectification_matrix", record.R),
        *_yaml_ros_matrix("projection_matrix", record.P),
    ]
    return "\n".join(lines) + "\n"


def from_ros_yaml(text: str) -> CalibrationRecord:
    """Return the record in ROS camera_info YAML text.

    Accepts distortion models plumb_bob and rational_polynomial. Raises InvalidInput when the
    text is malformed, a matrix has the wrong size, or the model is another (e.g. equidistant).
    """
    try:
        doc = yaml.safe_load(_text(text))
    except yaml.YAMLError as exc:
        raise InvalidInput(f"not valid ROS camera_info YAML: {exc}") from None
    if not isinstance(doc, dict):
        raise InvalidInput("ROS camera_info YAML must be a mapping of keys to values")
    model = doc.get("distortion_model", "plumb_bob")
    if model not in _ROS_MODELS.values():
        raise InvalidInput(
            f"unsupported distortion_model {model!r}; plumb_bob and rational_polynomial are read"
        )
    K = _ros_matrix(doc, "camera_matrix", (3, 3))
    dist = _ros_matrix(doc, "distortion_coefficients", None).ravel()
    expected = 5 if model == "plumb_bob" else 8
    if dist.size != expected:
        raise InvalidInput(f"distortion_model {model} has {expected} coefficients, got {dist.size}")
    R = _ros_matrix(doc, "rectification_matrix", (3, 3)) if "rectification_matrix" in doc else None
    P = _ros_matrix(doc, "projection_matrix", (3, 4)) if "projection_matrix" in doc else None
    name = doc.get("camera_name")
    return CalibrationRecord(
        K=K,
        dist=dist,
        image_size=(_int(doc, "image_width"), _int(doc, "image_height")),
        camera_name="camera" if name is None else str(name),
        rectification=R,
        projection=P,
    )


# --- helpers -----------------------------------------------------------------------------------


class _OpenCVLoader(yaml.SafeLoader):
    """SafeLoader that understands OpenCV's !!opencv-matrix tag and ignores other tags."""


def _construct_opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> dict[Any, Any]:
    # Kept as a mapping, like the JSON form, and checked once its key (the name) is known.
    if not isinstance(node, yaml.MappingNode):
        raise InvalidInput("an !!opencv-matrix must be a mapping with rows, cols, dt and data")
    return {**loader.construct_mapping(node, deep=True), "type_id": "opencv-matrix"}


def _construct_unknown(loader: yaml.SafeLoader, tag_suffix: str, node: yaml.Node) -> Any:
    # Other OpenCV tags (nested structures, user types) are read as plain data.
    if isinstance(node, yaml.MappingNode):
        return loader.construct_mapping(node, deep=True)
    if isinstance(node, yaml.SequenceNode):
        return loader.construct_sequence(node, deep=True)
    return loader.construct_scalar(node)


_OpenCVLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _construct_opencv_matrix)
_OpenCVLoader.add_multi_constructor("", _construct_unknown)


def _text(text: object) -> str:
    if isinstance(text, bytes):
        try:
            return text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise InvalidInput(f"calibration text is not UTF-8: {exc}") from None
    if not isinstance(text, str):
        raise InvalidInput(f"calibration text must be str, got {type(text).__name__}")
    if not text.strip():
        raise InvalidInput("calibration text is empty")
    return text


def _num(x: float) -> str:
    """Return the shortest text that reads back as exactly `x`, in a form YAML 1.1 and OpenCV
    both take as a float ("1e-05" would be a string to YAML 1.1, so it becomes "1.0e-05")."""
    r = repr(float(x))
    return r.replace("e", ".0e") if "e" in r and "." not in r else r


def _yaml_opencv_matrix(name: str, m: ArrayLike) -> list[str]:
    a = np.asarray(m, dtype=np.float64)
    data = ", ".join(_num(float(v)) for v in a.ravel())
    return [
        f"{name}: !!opencv-matrix",
        f"   rows: {a.shape[0]}",
        f"   cols: {a.shape[1]}",
        "   dt: d",
        f"   data: [ {data} ]",
    ]


def _json_opencv_matrix(m: ArrayLike) -> dict[str, Any]:
    a = np.asarray(m, dtype=np.float64)
    return {
        "type_id": "opencv-matrix",
        "rows": a.shape[0],
        "cols": a.shape[1],
        "dt": "d",
        "data": [float(v) for v in a.ravel()],
    }


def _yaml_ros_matrix(name: str, m: ArrayLike) -> list[str]:
    a = np.asarray(m, dtype=np.float64)
    data = ", ".join(_num(float(v)) for v in a.ravel())
    return [f"{name}:", f"  rows: {a.shape[0]}", f"  cols: {a.shape[1]}", f"  data: [{data}]"]


def _as_float_list(data: object, where: str) -> list[float]:
    if not isinstance(data, list):
        raise InvalidInput(f"{where}: data must be a list of numbers, got {type(data).__name__}")
    try:
        # float() also takes what YAML 1.1 leaves as text, such as "1e-05" (no decimal point).
        return [float(v) for v in data]
    except (TypeError, ValueError):
        raise InvalidInput(f"{where}: data must hold only numbers") from None


def _opencv_matrix(m: object, where: str) -> Array:
    """Return the array of an OpenCV matrix node {type_id?, rows, cols, dt, data}."""
    if not isinstance(m, dict) or not {"rows", "cols", "data"} <= m.keys():
        raise InvalidInput(f"{where} must be an opencv-matrix with rows, cols, dt and data")
    try:
        rows, cols = int(m["rows"]), int(m["cols"])
    except (TypeError, ValueError):
        raise InvalidInput(f"{where}: rows and cols must be integers") from None
    # dt is a type code such as "d", "f" or "3d": a leading count is the number of channels.
    dt = str(m.get("dt", "d"))
    channels = int(dt[:-1]) if dt[:-1].isdigit() else 1
    data = _as_float_list(m["data"], where)
    if rows < 0 or cols < 0 or len(data) != rows * cols * channels:
        raise InvalidInput(
            f"{where}: rows x cols x channels = {rows} x {cols} x {channels} but data has "
            f"{len(data)} values"
        )
    a = np.asarray(data, dtype=np.float64).reshape(rows, cols * channels)
    if not np.all(np.isfinite(a)):
        raise InvalidInput(f"{where} contains NaN or infinite values")
    return a


def _float(v: object, name: str) -> float:
    try:
        return float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InvalidInput(f"{name} must be a number, got {v!r}") from None


def _first(doc: dict[str, Any], keys: tuple[str, ...], fmt: str) -> Any:
    for k in keys:
        if k in doc:
            return doc[k]
    raise InvalidInput(f"{fmt} has no {keys[0]}; expected one of {', '.join(keys)}")


def _int(doc: dict[str, Any], key: str) -> int:
    v = doc.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or v != int(v):
        raise InvalidInput(f"{key} must be an integer number of pixels, got {v!r}")
    return int(v)


def _record_from_opencv(doc: object, fmt: str) -> CalibrationRecord:
    if not isinstance(doc, dict):
        raise InvalidInput(f"{fmt} must be a mapping of keys to values")
    K = _first(doc, _K_KEYS, fmt)
    dist = _first(doc, _DIST_KEYS, fmt)
    K = _opencv_matrix(K, "camera_matrix")
    dist = _opencv_matrix(dist, "distortion_coefficients")
    if "image_width" in doc or "image_height" in doc:
        size = (_int(doc, "image_width"), _int(doc, "image_height"))
    elif "cameraResolution" in doc:
        res = doc["cameraResolution"]
        if not (isinstance(res, list) and len(res) == 2):
            raise InvalidInput(f"cameraResolution must be [width, height], got {res!r}")
        size = (_int({"w": res[0]}, "w"), _int({"h": res[1]}, "h"))
    else:
        raise InvalidInput(f"{fmt} has no image_width and image_height")
    rms = doc.get("avg_reprojection_error")
    rms = None if rms is None else _float(rms, "avg_reprojection_error")
    name = doc.get("camera_name")
    return CalibrationRecord(
        K=K,
        dist=dist.ravel(),
        image_size=size,
        rms=rms,
        camera_name="camera" if name is None else str(name),
    )


def _ros_matrix(doc: dict[str, Any], key: str, shape: tuple[int, int] | None) -> Array:
    m = doc.get(key)
    if not isinstance(m, dict) or "data" not in m:
        raise InvalidInput(f"{key} must be a mapping with rows, cols and data")
    a = np.asarray(_as_float_list(m["data"], key), dtype=np.float64)
    try:
        rows, cols = int(m.get("rows", 1)), int(m.get("cols", a.size))
    except (TypeError, ValueError):
        raise InvalidInput(f"{key}: rows and cols must be integers") from None
    if rows * cols != a.size or (shape is not None and (rows, cols) != shape):
        want = "" if shape is None else f" (expected {shape[0]} x {shape[1]})"
        raise InvalidInput(f"{key}: rows x cols = {rows} x {cols}{want}, data has {a.size} values")
    if not np.all(np.isfinite(a)):
        raise InvalidInput(f"{key} contains NaN or infinite values")
    return a.reshape(rows, cols)
