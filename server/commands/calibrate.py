"""`intspace calibrate DIR`: calibrate a camera from a folder of photos of a calibration board.

Reads every photo in DIR, finds the pattern (chessboard, circle grid or ChArUco), calibrates with
core.calibration.calibrate_camera and prints the result (a summary, or one JSON object with
--json); optionally writes OpenCV FileStorage YAML and ROS camera_info YAML files. Bad input gives
a one-line message on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from core.calibration import DISTORTION_MODELS, CameraCalibration, calibrate_camera
from core.calibration.detect import (
    CharucoSpec,
    PatternDetection,
    board_object_points,
    find_charuco,
    find_chessboard,
    find_circle_grid,
)
from core.calibration.io import CalibrationRecord, to_opencv_yaml, to_ros_yaml
from core.errors import IntspaceError, PatternNotFound
from server.schemas.calibration import implausible_square

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".gif")
EXIT_USAGE = 2


class CommandError(Exception):
    """A problem with the command's input, reported as one line on stderr with exit code 2."""


@dataclass(frozen=True)
class _Photo:
    path: Path
    image: np.ndarray


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `calibrate` sub-command."""
    p = subparsers.add_parser(
        "calibrate",
        help="calibrate a camera from a folder of photos of a calibration board",
        description=(
            "Calibrate a camera (intrinsics and lens distortion, Zhang's method) from photos of a "
            "flat calibration board taken from different angles. Give exactly one pattern."
        ),
    )
    p.add_argument("folder", metavar="DIR", type=Path, help="folder with the photos")
    pattern = p.add_mutually_exclusive_group(required=True)
    pattern.add_argument(
        "--chessboard",
        metavar="COLSxROWS",
        type=_grid_size,
        help="chessboard with COLS x ROWS inner corners (OpenCV's pattern.png is 9x6)",
    )
    pattern.add_argument(
        "--circles",
        metavar="COLSxROWS",
        type=_grid_size,
        help="grid of dark circles, COLS per row x ROWS (see --asymmetric)",
    )
    pattern.add_argument(
        "--charuco",
        metavar="SXxSY",
        type=_grid_size,
        help="ChArUco board of SX x SY squares (see --dictionary, --marker-ratio)",
    )
    p.add_argument(
        "--square",
        metavar="METRES",
        type=_positive_length,
        required=True,
        help="side of a square (circle grids: the spacing), in metres",
    )
    p.add_argument(
        "--asymmetric",
        action="store_true",
        help="the circle grid is asymmetric (OpenCV's acircles_pattern.png is 4x11)",
    )
    p.add_argument(
        "--dictionary",
        default="DICT_5X5_100",
        help="ArUco dictionary of a ChArUco board (default: %(default)s)",
    )
    p.add_argument(
        "--marker-ratio",
        type=float,
        default=0.75,
        help="ChArUco marker side / square side (default: %(default)s)",
    )
    p.add_argument(
        "--distortion",
        default="k1k2p1p2",
        metavar="MODEL",
        help=f"distortion model: {', '.join(DISTORTION_MODELS)} (default: %(default)s)",
    )
    p.add_argument("--skew", action="store_true", help="also estimate the skew of the pixel axes")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a summary")
    p.add_argument("--output-yaml", metavar="FILE", type=Path, help="write OpenCV FileStorage YAML")
    p.add_argument("--ros-yaml", metavar="FILE", type=Path, help="write ROS camera_info YAML")
    p.add_argument("--camera-name", default="camera", help="camera name in the written files")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run `intspace calibrate`; return the exit code (0, or 2 on bad input)."""
    try:
        return _run(args)
    except (CommandError, IntspaceError) as exc:
        print(f"intspace calibrate: error: {exc}", file=sys.stderr)
        return EXIT_USAGE


def _run(args: argparse.Namespace) -> int:
    if (why := implausible_square(args.square)) is not None:
        raise CommandError(f"--square {args.square:g}: {why}")
    if args.distortion not in DISTORTION_MODELS:
        raise CommandError(
            f"unknown distortion model {args.distortion!r}; use one of "
            f"{', '.join(DISTORTION_MODELS)}"
        )
    for path in (args.output_yaml, args.ros_yaml):
        if path is not None and not path.parent.is_dir():
            raise CommandError(f"cannot write {path}: folder {path.parent} does not exist")
    detect, pattern_text = _detector(args)
    photos, skipped = _read_photos(args.folder)
    image_size = (photos[0].image.shape[1], photos[0].image.shape[0])

    views: list[tuple[Path, PatternDetection]] = []
    for photo in photos:
        try:
            views.append((photo.path, detect(photo.image)))
        except PatternNotFound:
            skipped.append((photo.path, "pattern not found"))
    need = 3 if args.skew else 2
    if len(views) < need:
        raise CommandError(
            f"the {pattern_text} was found in {len(views)} of {len(photos)} photos in "
            f"{args.folder}; calibration{' with --skew' if args.skew else ''} needs at least "
            f"{need} views (check the pattern size and that the whole board is in view)"
        )

    calib = calibrate_camera(
        [d.object_points(args.square) for _, d in views],
        [d.corners for _, d in views],
        image_size,
        skew=args.skew,
        distortion=args.distortion,
    )
    record = CalibrationRecord(
        K=calib.K,
        dist=calib.dist,
        image_size=image_size,
        rms=calib.rms,
        camera_name=args.camera_name,
    )
    _write(args.output_yaml, to_opencv_yaml(record))
    _write(args.ros_yaml, to_ros_yaml(record))

    if args.json:
        print(json.dumps(_as_json(args, pattern_text, calib, views, skipped), indent=2))
    else:
        print(_summary(args, pattern_text, calib, views, skipped, len(photos)))
    return 0


def _grid_size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or int(m[1]) < 2 or int(m[2]) < 2:
        raise argparse.ArgumentTypeError(
            f"expected COLSxROWS with two integers >= 2, such as 9x6; got {text!r}"
        )
    return int(m[1]), int(m[2])


def _positive_length(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not np.isfinite(v) or v <= 0.0:
        raise argparse.ArgumentTypeError(f"expected a positive length in metres; got {text!r}")
    return v


def _detector(args: argparse.Namespace) -> tuple[Callable[[np.ndarray], PatternDetection], str]:
    """Return the detector to apply to each photo and a description of the pattern."""
    if args.chessboard:
        size = args.chessboard
        return (lambda im: find_chessboard(im, size)), f"{size[0]}x{size[1]} chessboard"
    if args.circles:
        size, sym = args.circles, not args.asymmetric
        kind = "symmetric" if sym else "asymmetric"
        return (lambda im: find_circle_grid(im, size, sym)), (
            f"{kind} {size[0]}x{size[1]} circle grid"
        )
    sx, sy = args.charuco
    spec = CharucoSpec(sx, sy, args.marker_ratio, args.dictionary)
    board_object_points(spec, 1.0)  # checks the dictionary and ratio before any photo is read
    return (lambda im: find_charuco(im, spec)), f"{sx}x{sy} ChArUco board ({args.dictionary})"


def _read_photos(folder: Path) -> tuple[list[_Photo], list[tuple[Path, str]]]:
    """Return the readable photos of the most common size, and the files skipped with why."""
    if not folder.exists():
        raise CommandError(f"folder {folder} does not exist")
    if not folder.is_dir():
        raise CommandError(f"{folder} is not a folder; give the folder that holds the photos")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise CommandError(f"no photos in {folder} (looked for {', '.join(IMAGE_SUFFIXES)} files)")
    photos, skipped = [], []
    for path in files:
        image = _imread_grey(path)
        if image is None:
            print(f"intspace calibrate: warning: cannot read {path}; skipped", file=sys.stderr)
            skipped.append((path, "unreadable"))
        else:
            photos.append(_Photo(path, image))
    if not photos:
        raise CommandError(f"none of the {len(files)} image files in {folder} could be read")
    # All views must come from one camera mode; keep the most common size.
    size, _ = Counter(p.image.shape for p in photos).most_common(1)[0]
    for p in photos:
        if p.image.shape != size:
            print(
                f"intspace calibrate: warning: {p.path} is {p.image.shape[1]}x{p.image.shape[0]} "
                f"px, the others {size[1]}x{size[0]}; skipped",
                file=sys.stderr,
            )
            skipped.append((p.path, "different image size"))
    return [p for p in photos if p.image.shape == size], skipped


def _imread_grey(path: Path) -> np.ndarray | None:
    """Return the photo as a uint8 grey image, or None when it cannot be decoded."""
    try:
        # Via imdecode so that non-ASCII paths work on every platform.
        buf = np.fromfile(path, dtype=np.uint8)
        image = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE) if buf.size else None
        if image is None and path.suffix.lower() == ".gif":
            # OpenCV builds without the GIF codec can still read it through a video backend.
            cap = cv2.VideoCapture(str(path))
            ok, frame = cap.read()
            cap.release()
            image = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if ok and frame is not None else None
    except (OSError, cv2.error):
        return None
    return image


def _write(path: Path | None, text: str) -> None:
    if path is None:
        return
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise CommandError(f"cannot write {path}: {exc.strerror or exc}") from None


def _as_json(
    args: argparse.Namespace,
    pattern_text: str,
    calib: CameraCalibration,
    views: list[tuple[Path, PatternDetection]],
    skipped: list[tuple[Path, str]],
) -> dict[str, Any]:
    return {
        "K": calib.K.tolist(),
        "dist": calib.dist.tolist(),
        "rms": calib.rms,
        "std_intrinsics": {k: float(v) for k, v in calib.std_intrinsics.items()},
        "image_size": list(calib.image_size),
        "distortion_model": args.distortion,
        "skew": bool(args.skew),
        "pattern": pattern_text,
        "square_size": args.square,
        "views": [
            {
                "file": path.name,
                "rms": float(rms),
                "points": len(d.corners),
                "rvec": rvec.tolist(),
                "tvec": tvec.tolist(),
            }
            for (path, d), rms, rvec, tvec in zip(
                views, calib.per_view_rms, calib.rvecs, calib.tvecs, strict=True
            )
        ],
        "skipped": [{"file": p.name, "reason": why} for p, why in skipped],
    }


def _summary(
    args: argparse.Namespace,
    pattern_text: str,
    calib: CameraCalibration,
    views: list[tuple[Path, PatternDetection]],
    skipped: list[tuple[Path, str]],
    n_photos: int,
) -> str:
    w, h = calib.image_size
    std = calib.std_intrinsics
    lines = [
        f"Calibrated from {len(views)} of {n_photos} photos in {args.folder} ({w}x{h} px): "
        f"{pattern_text}, {args.square:g} m {'spacing' if args.circles else 'squares'}, "
        f"distortion model {args.distortion}"
        f"{', with skew' if args.skew else ''}",
        "",
        "K (px) =",
        *(f"  [{' '.join(f'{v:12.4f}' for v in row)} ]" for row in calib.K),
        "dist (k1, k2, p1, p2, k3) = [" + ", ".join(f"{v:.6g}" for v in calib.dist) + "]",
        f"RMS reprojection error: {calib.rms:.4f} px",
        "Standard deviations: " + ", ".join(f"{k} {v:.3g}" for k, v in std.items() if v > 0.0),
        "",
        "Per-view RMS (px):",
        *(
            f"  {path.name:<32} {rms:8.4f}  ({len(d.corners)} points)"
            for (path, d), rms in zip(views, calib.per_view_rms, strict=True)
        ),
    ]
    not_found = [p.name for p, why in skipped if why == "pattern not found"]
    if not_found:
        lines += ["", f"Pattern not found in: {', '.join(not_found)}"]
    other = [f"{p.name} ({why})" for p, why in skipped if why != "pattern not found"]
    if other:
        lines += [f"Skipped: {', '.join(other)}"]
    for label, path in (("OpenCV YAML", args.output_yaml), ("ROS camera_info", args.ros_yaml)):
        if path is not None:
            lines.append(f"Wrote {label} to {path}")
    return "\n".join(lines)
