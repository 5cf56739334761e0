"""`intspace node`: read cameras, detect the robot and people in their frames, post the
detections to the service (spec 08).

    intspace node --source SRC --camera NAME [--space ID] [--api URL] [--fps N]
        [--detector dnn|background] [--score-threshold S] [--min-person-px PX] [--[no-]flip]
        [--tile-px PX] [--mask "X,Y X,Y X,Y" ...] [--source-fps N]
    intspace node --config cameras.yaml [--api URL]
    intspace node ... --record DIR          (keep frames, detections, capture times)
    intspace node --source DIR --camera NAME [--fast]   (replay a recording)
    intspace node calibrate --camera NAME --board 9x6 --square 0.025 [--apply]

SRC: a USB index, a video file, an RTSP or HTTP(S) MJPEG URL (the service's own
/api/v1/cameras/{id}/stream.mjpg included). The token comes from INTSPACE_TOKEN only (never a
flag: command lines are visible to every user of the machine).

Exit codes, each failure said in one line on stderr: 0 when every source ended (video files)
or the node was stopped (Ctrl-C, SIGTERM); 1 when a camera's detection failed (its detector
raised) or a fast replay fell behind its clip; 2 for a bad command line or configuration file, no
token, or a camera the registry does not know or has not calibrated; 3 for a source that cannot
be opened at start (no such file, connection refused, ...). A stream that drops later is
reopened with back-off, never an exit.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

from pydantic import ValidationError

from core.errors import InvalidInput
from server.node.client import DEFAULT_API, api_url

EXIT_USAGE = 2
EXIT_SOURCE = 3


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `node` command."""
    p = subparsers.add_parser(
        "node",
        help="read cameras and post their detections to the service",
        description="Read cameras (USB, video file, RTSP, HTTP MJPEG), detect the robot's "
        "marker and people in each frame, and post the detections to the service. The token "
        "is read from INTSPACE_TOKEN.",
    )
    p.add_argument("--config", type=Path, metavar="FILE", help="YAML file of cameras")
    p.add_argument("--source", metavar="SRC", help="one camera's source")
    p.add_argument("--camera", metavar="NAME", help="its name in the registry")
    p.add_argument("--space", type=int, metavar="ID", help="the space the camera belongs to")
    p.add_argument("--api", metavar="URL", help=f"the service (default {DEFAULT_API})")
    p.add_argument("--fps", type=float, metavar="N", help="detections per second at most")
    p.add_argument(
        "--fast",
        action="store_true",
        help="replay a video file or recording as fast as it is detected in: every frame, "
        "stamped with the clip's own timing",
    )
    p.add_argument(
        "--summary",
        type=float,
        metavar="S",
        default=60.0,
        help="log what the node did every S seconds (default 60; 0: only at the end)",
    )
    p.add_argument(
        "--source-fps",
        type=float,
        metavar="N",
        help="a video file's true frame rate: frame k is captured at the start + k / N s and "
        "played at N frames per second (its container's rate can be wrong)",
    )
    p.add_argument(
        "--detector",
        choices=["auto", "dnn", "background"],
        help="the people detector: dnn (neural, for real cameras), background (background "
        "subtraction, for the twin's cameras); auto (default): background for the service's "
        "own streams, dnn otherwise",
    )
    p.add_argument(
        "--score-threshold",
        type=float,
        metavar="S",
        help="dnn: the least score of a person's box (default 0.5)",
    )
    p.add_argument(
        "--min-person-px",
        type=float,
        metavar="PX",
        help="dnn: the least height of a person's box in pixels (default 20)",
    )
    p.add_argument(
        "--flip",
        action=argparse.BooleanOptionalAction,
        help="dnn: also detect in each tile's mirror image (more people found, twice the cost)",
    )
    p.add_argument(
        "--tile-px",
        type=int,
        metavar="PX",
        help="dnn: the side of the tiles the frame is cut into, each enlarged to the model's "
        "300 px (default 230: 1.3 times; larger tiles are fewer and find fewer far people)",
    )
    p.add_argument(
        "--mask",
        action="append",
        metavar='"X,Y X,Y X,Y"',
        help="a polygon of pixels to ignore (repeatable)",
    )
    p.add_argument(
        "--background-frames",
        type=int,
        metavar="N",
        help="frames that teach the background model (default 30)",
    )
    p.add_argument("--marker-colour", metavar="R,G,B", help="the robot marker's colour")
    p.add_argument("--marker-height", type=float, metavar="M", help="its height (m)")
    p.add_argument(
        "--record",
        type=Path,
        metavar="DIR",
        help="keep the frames, detections and capture times in DIR (a new folder), to replay "
        "later with --source DIR",
    )
    p.set_defaults(func=run_node)
    from server.node import calibrate

    calibrate.register(p.add_subparsers(dest="node_command", metavar="{calibrate}"))


def _fail(message: str, code: int = EXIT_USAGE) -> int:
    print(f"intspace node: error: {' '.join(message.split())}", file=sys.stderr, flush=True)
    return code


def _polygon(text: str) -> list[list[float]]:
    """Return the vertices of a --mask polygon "X,Y X,Y X,Y"."""
    try:
        vertices = [[float(v) for v in point.split(",")] for point in text.split()]
    except ValueError:
        vertices = []
    if len(vertices) < 3 or any(len(v) != 2 for v in vertices):
        raise InvalidInput(f'--mask {text!r}: give at least 3 pixel vertices "X,Y X,Y X,Y"')
    return vertices


# The flags that set one camera's settings (a camera of a --config file has its own), copied as
# given onto the camera of --source and --camera; --mask is one too, parsed first.
_CAMERA_FLAGS = ("detector", "score_threshold", "min_person_px", "flip", "tile_px", "source_fps")


def _config(args: argparse.Namespace):
    from server.node.config import CameraConfig, NodeConfig, load_config, parse_source

    if args.config is not None:
        per_camera = (*_CAMERA_FLAGS, "mask")
        if args.source or args.camera or any(getattr(args, n) is not None for n in per_camera):
            raise InvalidInput(
                "give --config, or --source and --camera (with their camera's flags), not both"
            )
        try:
            text = args.config.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise InvalidInput(f"cannot read {args.config}: {exc}") from exc
        try:
            config = load_config(text)
        except InvalidInput as exc:
            raise InvalidInput(f"{args.config}: {exc}") from exc
    else:
        if not args.source or not args.camera:
            raise InvalidInput("give --source and --camera (or --config FILE)")
        fields: dict = {
            "name": args.camera,
            "source": parse_source(args.source),
            "fps": args.fps,
            "realtime": not args.fast,
            "masks": [_polygon(text) for text in args.mask or []],
        }
        for name in _CAMERA_FLAGS:
            if getattr(args, name) is not None:
                fields[name] = getattr(args, name)
        try:
            camera = CameraConfig(**fields)
        except ValidationError as exc:
            first = exc.errors()[0]
            flag = "--" + str(first["loc"][0]).replace("_", "-")
            raise InvalidInput(f"{flag}: {first['msg']}") from exc
        config = NodeConfig(cameras=[camera])
    changes: dict = {}
    if args.space is not None:
        changes["space"] = args.space
    if args.background_frames is not None:
        changes["background_frames"] = max(0, args.background_frames)
    marker = config.marker.model_copy()
    if args.marker_colour:
        try:
            colour = tuple(int(c) for c in args.marker_colour.split(","))
        except ValueError as exc:
            raise InvalidInput("--marker-colour must be R,G,B integers 0..255") from exc
        if len(colour) != 3 or not all(0 <= c <= 255 for c in colour):
            raise InvalidInput("--marker-colour must be R,G,B integers 0..255")
        marker = marker.model_copy(update={"colour": colour})
    if args.marker_height is not None:
        if not 0 < args.marker_height <= 5:
            raise InvalidInput("--marker-height must lie in (0, 5] metres")
        marker = marker.model_copy(update={"height": args.marker_height})
    changes["marker"] = marker
    return config.model_copy(update=changes)


def run_node(args: argparse.Namespace) -> int:
    """Run the node until SIGINT/SIGTERM (or until every video file ended)."""
    from server.commands._signals import stop_on_signals
    from server.node.client import NodeError
    from server.node.runner import Node
    from server.node.sources import SourceUnavailable, quiet_video_libraries

    quiet_video_libraries()
    logging.basicConfig(level=logging.INFO, format="intspace node: %(message)s", stream=sys.stderr)
    logging.getLogger("httpx").setLevel(logging.WARNING)
    token = os.environ.get("INTSPACE_TOKEN", "").strip()
    if not token:
        return _fail("set INTSPACE_TOKEN to a token with the write scope")
    try:
        config = _config(args)
    except InvalidInput as exc:
        return _fail(str(exc))
    if not 0 <= args.summary <= 86_400:
        return _fail("--summary must lie in [0, 86400] seconds")
    api = api_url(args.api or config.api or DEFAULT_API)
    node = Node(config, api, token, summary_s=args.summary)
    try:
        node.prepare()
        if args.record is not None:
            node.record(args.record)
    except SourceUnavailable as exc:
        node.client.close()
        return _fail(str(exc), EXIT_SOURCE)
    except (NodeError, InvalidInput) as exc:
        node.client.close()
        return _fail(str(exc))

    stop_on_signals(node.stop_event)
    return node.run()
