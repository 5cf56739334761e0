"""`intspace landmark make|detect`: print landmarks at true size, find and read them in a photo.

* `make --kind object|signpost --id N --name TEXT [--size METRES] --out FILE.svg|.pdf|.png`:
  the payload (core.landmarks.payload) in a QR symbol inside the blue frame (object mark) or
  the red rings (signpost), with the id and name under it; SVG and PDF print at true size, PNG
  at --ppm pixels per metre.
* `detect IMAGE --camera FILE.yaml [--json]`: every landmark in the photo, with its pose
  T_cam_mark, covariance and decoded record (core.landmarks.detect_landmarks); the camera file
  is OpenCV FileStorage YAML as `intspace calibrate --output-yaml` writes it.

Bad input gives a one-line message on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from core.calibration.io import from_opencv_yaml
from core.errors import IntspaceError
from core.landmarks import ObjectMark, Signpost
from core.landmarks.artwork import DEFAULT_SIZE, make_artwork, to_pdf, to_png, to_svg
from core.landmarks.detect import LandmarkDetection, detect_landmarks

EXIT_USAGE = 2
_FORMATS = (".svg", ".pdf", ".png")


class CommandError(Exception):
    """A problem with the command's input, reported as one line on stderr with exit code 2."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `landmark` sub-command with its `make` and `detect` actions."""
    p = subparsers.add_parser(
        "landmark",
        help="make printable QR landmarks, or find and read them in a photo",
        description="Make printable QR landmarks (object marks, signposts) or detect them.",
    )
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    m = sub.add_parser("make", help="write a landmark's artwork (SVG, PDF or PNG)")
    m.add_argument("--kind", required=True, choices=("object", "signpost"))
    m.add_argument("--id", required=True, type=int, help="landmark id (0-999999999)")
    m.add_argument("--name", required=True, help="human label (object name or place name)")
    m.add_argument(
        "--size",
        type=float,
        default=None,
        help="outer side of the blue frame / outer diameter of the red rings, metres "
        "(default 0.10 / 0.20)",
    )
    m.add_argument("--room", default="unassigned", help="room the landmark is in")
    m.add_argument("--object-class", default="object", help="object class (object marks)")
    m.add_argument(
        "--object-size", default="0,0,0", help="object extent sx,sy,sz metres (object marks)"
    )
    m.add_argument("--hint", action="append", default=[], help="handling hint (repeatable)")
    m.add_argument(
        "--pose",
        default="0,0,0,0,0,0,1",
        help="signpost pose in the world x,y,z,qx,qy,qz,qw (metres, quaternion)",
    )
    m.add_argument(
        "--neighbours", default="", help="ids of neighbouring signposts, comma-separated"
    )
    m.add_argument("--ppm", type=float, default=5000.0, help="PNG pixels per metre (default 5000)")
    m.add_argument("--out", required=True, type=Path, help="FILE.svg, FILE.pdf or FILE.png")
    m.set_defaults(func=run_make)
    d = sub.add_parser("detect", help="find, locate and read landmarks in a photo")
    d.add_argument("image", type=Path, metavar="IMAGE")
    d.add_argument("--camera", required=True, type=Path, help="OpenCV YAML calibration")
    d.add_argument("--frame-size", type=float, default=DEFAULT_SIZE["object"])
    d.add_argument("--ring-size", type=float, default=DEFAULT_SIZE["signpost"])
    d.add_argument("--json", action="store_true", help="print one JSON object")
    d.set_defaults(func=run_detect)


def _guard(name: str, fn: Any, args: argparse.Namespace) -> int:
    try:
        return int(fn(args))
    except (CommandError, IntspaceError) as exc:
        print(f"intspace landmark {name}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE


def run_make(args: argparse.Namespace) -> int:
    """Run `intspace landmark make`; return the exit code (0, or 2 on bad input)."""
    return _guard("make", _make, args)


def run_detect(args: argparse.Namespace) -> int:
    """Run `intspace landmark detect`; return the exit code (0, or 2 on bad input)."""
    return _guard("detect", _detect, args)


def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise CommandError(f"{what} must be {n} comma-separated numbers, got {text!r}") from None
    if len(v) != n:
        raise CommandError(f"{what} must be {n} comma-separated numbers, got {text!r}")
    return v


def _make(args: argparse.Namespace) -> int:
    suffix = args.out.suffix.lower()
    if suffix not in _FORMATS:
        raise CommandError(f"--out must end in .svg, .pdf or .png, got {args.out.name!r}")
    record: ObjectMark | Signpost
    if args.kind == "object":
        record = ObjectMark(
            id=args.id,
            object_class=args.object_class,
            name=args.name,
            room=args.room,
            size=_floats(args.object_size, 3, "--object-size"),  # type: ignore[arg-type]
            hints=tuple(args.hint),
        )
    else:
        try:
            nbs = tuple(int(x) for x in args.neighbours.split(",") if x.strip())
        except ValueError:
            raise CommandError(
                f"--neighbours must be integer ids, got {args.neighbours!r}"
            ) from None
        record = Signpost(
            id=args.id,
            name=args.name,
            room=args.room,
            pose=_floats(args.pose, 7, "--pose"),
            neighbours=nbs,
        )
    art = make_artwork(record, size=args.size)
    data: bytes
    if suffix == ".svg":
        data = to_svg(art).encode()
    elif suffix == ".pdf":
        data = to_pdf(art)
    else:
        data = to_png(art, args.ppm)
    try:
        args.out.write_bytes(data)
    except OSError as exc:
        raise CommandError(f"cannot write {args.out}: {exc.strerror}") from None
    what = "object mark" if art.kind == "object" else "signpost"
    pattern = "frame" if art.kind == "object" else "rings"
    print(
        f"wrote {args.out}: {what} #{args.id}, {1000 * art.size:g} mm {pattern}, "
        f"{len(art.modules)}x{len(art.modules)} modules of {art.module_mm:.2f} mm"
    )
    return 0


def _detect(args: argparse.Namespace) -> int:
    try:
        cam = from_opencv_yaml(args.camera.read_text())
    except OSError as exc:
        raise CommandError(f"cannot read {args.camera}: {exc.strerror}") from None
    buf = _read_bytes(args.image)
    img = cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise CommandError(f"{args.image} is not an image OpenCV can read")
    h, w = img.shape[:2]
    if (w, h) != tuple(cam.image_size):
        raise CommandError(
            f"{args.image} is {w}x{h} but the camera was calibrated at "
            f"{cam.image_size[0]}x{cam.image_size[1]}; use that camera's full-size images"
        )
    dist = cam.dist[:5] if cam.dist.size >= 5 else cam.dist
    if cam.dist.size > 5 and np.any(cam.dist[5:]):
        raise CommandError("the camera's rational or thin-prism distortion terms are not supported")
    dets = detect_landmarks(img, cam.K, dist, frame_size=args.frame_size, ring_size=args.ring_size)
    if args.json:
        print(json.dumps({"image": str(args.image), "detections": [_as_json(d) for d in dets]}))
        return 0
    print(f"{args.image}: {len(dets)} landmark(s)")
    for d in dets:
        p = d.position
        n = d.normal
        read = d.text if d.record is None else f"{d.record.kind} #{d.record.id} {d.record.name!r}"
        why = "" if d.reason is None else f" (not read: {d.reason})"
        if not d.decided:
            # The image cannot decide between the rings' two poses: say so, with both normals.
            m = d.hypotheses[1].normal
            why += (
                f"; undecided pose (p = {d.probability:.2f}), or normal "
                f"({m[0]:+.3f}, {m[1]:+.3f}, {m[2]:+.3f})"
            )
        print(
            f"  {d.kind:8s} at ({p[0]:+.3f}, {p[1]:+.3f}, {p[2]:+.3f}) m, normal "
            f"({n[0]:+.3f}, {n[1]:+.3f}, {n[2]:+.3f}), "
            f"sd {1000 * float(np.sqrt(np.trace(d.cov[3:, 3:]))):.1f} mm: {read or ''}{why}"
        )
    return 0


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise CommandError(f"cannot read {path}: {exc.strerror}") from None


def _as_json(d: LandmarkDetection) -> dict[str, Any]:
    record = None
    if d.record is not None:
        record = {"kind": d.record.kind, **asdict(d.record)}
    return {
        "kind": d.kind,
        "outline": d.outline.tolist(),
        "T_cam_mark": d.T_cam_mark.tolist(),
        "cov": d.cov.tolist(),
        "position": d.position.tolist(),
        "normal": d.normal.tolist(),
        "orientation_known": d.orientation_known,
        "record": record,
        "reason": d.reason,
        "text": d.text,
        "decided": d.decided,
        "hypotheses": [
            {"T_cam_mark": h.T.tolist(), "cov": h.cov.tolist(), "probability": h.probability}
            for h in d.hypotheses
        ],
    }
