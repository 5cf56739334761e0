"""`intspace node calibrate`: calibrate a camera's intrinsics from its live stream.

The user holds a printed chessboard in front of the camera and moves it about; a view is kept
whenever the board is seen somewhere the kept views have not covered yet: at another position,
size or tilt (ROS camera_calibration's coverage, its `get_parameters` and `is_good_sample`). Each
view is described by four numbers in [0, 1]:

* x, y: where the board's corners lie, their mean shrunk by half the board's size on each side
  (a large board cannot move far, and is not penalised for it);
* size: sqrt(area of the board's outline / area of the image);
* skew: how far the outline's corner angle is from a right angle, 2 |pi/2 - angle|, capped at 1.

A view is new when the L1 distance of its four numbers to every kept view's exceeds 0.2. The
coverage of each number is the span of the kept views' values over the span a good set needs
(x 0.7, y 0.7, size 0.4, skew 0.5, from 0 for size and skew: small and flat views are not a
merit), as ROS shows in its progress bars. The capture ends at `max_views` views, or when every
bar is full and `min_views` views are kept; the views (the stream's own JPEG bytes when it sent
JPEG, else lossless PNG) are then uploaded as a photo calibration run (POST
/calibration-runs/upload), whose result is printed and applied when the user agrees.

Boards are found with core.calibration.detect.find_chessboard, what the run itself uses, so a
kept view is a view the run can use.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

log = logging.getLogger("intspace.node")

EXIT_USAGE = 2
EXIT_FAILED = 1
EXIT_SOURCE = 3  # the camera's stream cannot be opened (as `intspace node`)
# ROS camera_calibration's spans of x, y, size and skew that make a good set of views.
PARAM_RANGES = np.array([0.7, 0.7, 0.4, 0.5])
PARAM_NAMES = ("X", "Y", "Size", "Skew")
# ROS's threshold of a new view: the L1 distance of its parameters to every kept view's.
MIN_PARAM_DISTANCE = 0.2
# The image grid shown as the views cover it (columns, rows).
GRID = (6, 4)
# Views a Zhang calibration with lens distortion needs at the very least.
MIN_VIEWS_TO_SUBMIT = 4


# -- coverage (pure) ------------------------------------------------------------------------------


def board_view_params(
    corners: NDArray[np.float64], pattern_size: tuple[int, int], image_size: tuple[int, int]
) -> NDArray[np.float64]:
    """Return (x, y, size, skew) in [0, 1] of a chessboard seen at `corners` (N, 2) px, row by
    row of `pattern_size` (cols, rows) inner corners, in an image of `image_size` (width,
    height) px: ROS camera_calibration's `get_parameters` (see the module's docstring)."""
    cols, rows = pattern_size
    pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    if pts.shape[0] != cols * rows:
        raise ValueError(f"{pts.shape[0]} corners for a {cols}x{rows} board")
    width, height = image_size
    up_left, up_right = pts[0], pts[cols - 1]
    down_right, down_left = pts[-1], pts[-cols]
    # The outline's area: half the cross product of its diagonals (any quadrilateral).
    d1, d2 = down_right - up_left, down_left - up_right
    area = 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])
    ab, cb = up_left - up_right, down_right - up_right
    cos = float(ab @ cb) / max(float(np.linalg.norm(ab) * np.linalg.norm(cb)), 1e-12)
    angle = float(np.arccos(np.clip(cos, -1.0, 1.0)))
    skew = min(1.0, 2.0 * abs(np.pi / 2 - angle))
    border = float(np.sqrt(area))
    mean = pts.mean(axis=0)
    x = (mean[0] - border / 2) / max(width - border, 1e-9)
    y = (mean[1] - border / 2) / max(height - border, 1e-9)
    size = float(np.sqrt(area / (width * height)))
    return np.clip(np.array([x, y, size, skew]), 0.0, 1.0)


@dataclass
class Coverage:
    """The views kept so far: their parameters and which cells of the image their corners
    reached."""

    image_size: tuple[int, int]
    params: list[NDArray[np.float64]] = field(default_factory=list)
    cells: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(GRID[::-1], dtype=bool))

    def is_new(self, params: NDArray[np.float64]) -> bool:
        """Return whether a view with `params` lies farther than MIN_PARAM_DISTANCE (L1) from
        every kept view."""
        if not self.params:
            return True
        kept = np.asarray(self.params)
        return bool(np.min(np.abs(kept - params).sum(axis=1)) > MIN_PARAM_DISTANCE)

    def add(self, params: NDArray[np.float64], corners: NDArray[np.float64]) -> None:
        """Keep a view: its parameters and the image cells its corners fall in."""
        self.params.append(np.asarray(params, dtype=np.float64))
        width, height = self.image_size
        pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
        cx = np.clip((pts[:, 0] / width * GRID[0]).astype(int), 0, GRID[0] - 1)
        cy = np.clip((pts[:, 1] / height * GRID[1]).astype(int), 0, GRID[1] - 1)
        self.cells[cy, cx] = True

    @property
    def progress(self) -> NDArray[np.float64]:
        """Return the coverage (4,) of x, y, size and skew, each in [0, 1]."""
        if not self.params:
            return np.zeros(4)
        kept = np.asarray(self.params)
        lo, hi = kept.min(axis=0), kept.max(axis=0)
        lo[2:] = 0.0  # small or flat views are no merit: size and skew count from 0
        return np.minimum((hi - lo) / PARAM_RANGES, 1.0)

    @property
    def complete(self) -> bool:
        """Return whether every parameter's span is covered."""
        return bool(np.all(self.progress >= 1.0))

    def render(self) -> str:
        """Return the coverage as text: a bar per parameter and the image's grid of cells
        reached by a kept view's corners (# reached, . not yet)."""
        lines = []
        for name, value in zip(PARAM_NAMES, self.progress, strict=True):
            filled = round(20 * float(value))
            lines.append(f"  {name:<5} [{'#' * filled}{'-' * (20 - filled)}] {100 * value:3.0f}%")
        grid = ["".join("#" if c else "." for c in row) for row in self.cells]
        lines.append(f"  image {grid[0]}   {int(self.cells.sum())}/{self.cells.size} cells")
        lines += [f"        {row}" for row in grid[1:]]
        return "\n".join(lines)


@dataclass(frozen=True)
class CapturedView:
    """A kept view: the image file to upload (bytes, name, type), the board's corners and its
    coverage parameters."""

    data: bytes
    filename: str
    content_type: str
    corners: NDArray[np.float64]
    params: NDArray[np.float64]


class BoardCapture:
    """Keeps the views of a chessboard that add coverage; `offer` one frame at a time."""

    def __init__(
        self,
        pattern_size: tuple[int, int],
        image_size: tuple[int, int],
        *,
        max_views: int = 25,
        min_views: int = 10,
    ) -> None:
        self.pattern_size = pattern_size
        self.image_size = image_size
        self.max_views = int(max_views)
        self.min_views = min(int(min_views), self.max_views)
        self.coverage = Coverage(image_size)
        self.views: list[CapturedView] = []
        self.frames = 0
        self.seen = 0  # frames in which the board was found

    @property
    def done(self) -> bool:
        """Return whether enough views are kept: `max_views`, or full coverage with at least
        `min_views`."""
        n = len(self.views)
        return n >= self.max_views or (self.coverage.complete and n >= self.min_views)

    def offer(self, image: NDArray[np.uint8], jpeg: bytes | None = None) -> CapturedView | None:
        """Look for the board in `image` (BGR or grey, the camera's size); keep the frame when
        the board is at a new position, size or tilt and return the kept view, else None.
        `jpeg`: the frame's bytes as the camera sent them (uploaded as they are)."""
        import cv2

        from core.calibration.detect import find_chessboard
        from core.errors import InvalidInput, PatternNotFound

        self.frames += 1
        try:
            found = find_chessboard(image, self.pattern_size)
        except (PatternNotFound, InvalidInput):
            return None
        self.seen += 1
        params = board_view_params(found.corners, self.pattern_size, self.image_size)
        if not self.coverage.is_new(params):
            return None
        if jpeg is not None:
            data, suffix, kind = jpeg, "jpg", "image/jpeg"
        else:
            ok, buf = cv2.imencode(".png", image)
            if not ok:  # pragma: no cover - an 8-bit image always encodes
                return None
            data, suffix, kind = buf.tobytes(), "png", "image/png"
        view = CapturedView(
            data, f"view-{len(self.views) + 1:03d}.{suffix}", kind, found.corners, params
        )
        self.views.append(view)
        self.coverage.add(params, found.corners)
        return view


# -- the command ----------------------------------------------------------------------------------


class CalibrateError(Exception):
    """A problem reported as one line on stderr (exit code 2 for bad input, else 1)."""

    def __init__(self, message: str, code: int = EXIT_FAILED) -> None:
        super().__init__(message)
        self.code = code


def _board(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d{1,3})\s*[xX]\s*(\d{1,3})\s*", text)
    if not m or int(m[1]) < 2 or int(m[2]) < 2:
        raise argparse.ArgumentTypeError(
            f"expected COLSxROWS inner corners, two integers >= 2, such as 9x6; got {text!r}"
        )
    return int(m[1]), int(m[2])


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not np.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number; got {text!r}")
    return value


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `node calibrate`."""
    p = subparsers.add_parser(
        "calibrate",
        help="calibrate a camera's intrinsics from its live stream and a chessboard",
        description="Show a printed chessboard to a camera and move it about: views are kept "
        "automatically when the board is at a new position, size and tilt, with the coverage "
        "printed as it fills; then they are submitted as a calibration run, its result is "
        "printed and, when you agree (or with --apply), applied to the camera. The token "
        "(write scope) is read from INTSPACE_TOKEN.",
    )
    p.add_argument("--camera", required=True, metavar="NAME", help="its name in the registry")
    p.add_argument(
        "--board", required=True, type=_board, metavar="COLSxROWS", help="inner corners, e.g. 9x6"
    )
    p.add_argument(
        "--square", required=True, type=_positive, metavar="METRES", help="a square's side (m)"
    )
    p.add_argument(
        "--source",
        metavar="SRC",
        help="the camera's stream (USB index, RTSP/HTTP URL, file); default: the service's "
        "stream of the camera (/cameras/{id}/stream.mjpg)",
    )
    p.add_argument("--space", type=int, metavar="ID", help="the space the camera belongs to")
    p.add_argument("--api", metavar="URL", help="the service (default http://127.0.0.1:8000)")
    p.add_argument(
        "--views", type=int, default=25, metavar="N", help="views to keep at most (default 25)"
    )
    p.add_argument(
        "--min-views",
        type=int,
        default=10,
        metavar="N",
        help="views that end the capture once the coverage is full (default 10)",
    )
    p.add_argument(
        "--timeout",
        type=_positive,
        default=600.0,
        metavar="S",
        help="stop capturing after S seconds and submit the views kept (default 600)",
    )
    p.add_argument(
        "--distortion",
        default="k1k2p1p2",
        choices=["none", "k1", "k1k2", "k1k2p1p2", "k1k2p1p2k3"],
        help="lens distortion coefficients fitted (default k1k2p1p2)",
    )
    p.add_argument("--apply", action="store_true", help="apply the result without asking")
    p.set_defaults(func=run_calibrate)


def run_calibrate(args: argparse.Namespace) -> int:
    """Run `intspace node calibrate`; return the exit code."""
    logging.basicConfig(level=logging.INFO, format="intspace node: %(message)s", stream=sys.stderr)
    logging.getLogger("httpx").setLevel(logging.WARNING)
    try:
        return _calibrate(args, input_fn=input)
    except CalibrateError as exc:
        print(f"intspace node calibrate: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return exc.code


def _say(text: str) -> None:
    print(text, flush=True)


def _calibrate(args: argparse.Namespace, input_fn: Callable[[str], str]) -> int:
    from server.node.client import DEFAULT_API, NodeError, ServiceClient, api_url
    from server.node.config import CameraConfig, parse_source
    from server.node.runner import make_source
    from server.node.sources import SourceUnavailable, quiet_video_libraries
    from server.schemas.calibration import implausible_square

    quiet_video_libraries()

    token = os.environ.get("INTSPACE_TOKEN", "").strip()
    if not token:
        raise CalibrateError("set INTSPACE_TOKEN to a token with the write scope", EXIT_USAGE)
    if (why := implausible_square(args.square)) is not None:
        raise CalibrateError(f"--square {args.square:g}: {why}", EXIT_USAGE)
    if not 1 <= args.views <= 60 or args.min_views < MIN_VIEWS_TO_SUBMIT:
        raise CalibrateError(
            f"--views must lie in 1..60 (the service takes 60 photos a run) and --min-views "
            f"be at least {MIN_VIEWS_TO_SUBMIT}",
            EXIT_USAGE,
        )
    api = api_url(args.api or DEFAULT_API)
    client = ServiceClient(api, token, timeout=30.0)
    try:
        try:
            row = client.camera(args.camera, args.space)
        except NodeError as exc:
            raise CalibrateError(str(exc), EXIT_USAGE) from None
        camera_id, size = int(row["id"]), (int(row["width"]), int(row["height"]))
        address = (
            parse_source(args.source) if args.source else f"{api}/cameras/{camera_id}/stream.mjpg"
        )
        config = CameraConfig(name=args.camera, source=address, realtime=True)
        capture = BoardCapture(args.board, size, max_views=args.views, min_views=args.min_views)
        _say(
            f"Calibrating camera {args.camera!r} (id {camera_id}, {size[0]}x{size[1]} px) from "
            f"{address}: show it the {args.board[0]}x{args.board[1]} chessboard and move it "
            "across the image, near and far, tilted left, right, up and down."
        )
        source = make_source(config, api, token)
        try:
            source.check()
        except SourceUnavailable as exc:
            raise CalibrateError(str(exc), EXIT_SOURCE) from None
        _capture(source, capture, args.timeout)
        if len(capture.views) < MIN_VIEWS_TO_SUBMIT:
            raise CalibrateError(
                f"only {len(capture.views)} view(s) kept ({capture.seen} of {capture.frames} "
                f"frames showed the {args.board[0]}x{args.board[1]} board); a calibration needs "
                f"{MIN_VIEWS_TO_SUBMIT}: check the board size (inner corners) and that the "
                "whole board with its white border is in view"
            )
        run = _submit(client, camera_id, args, capture)
        _say(f"Submitted calibration run {run['id']} with {len(capture.views)} views.")
        run = _wait_for(client, int(run["id"]))
        if run["status"] != "succeeded":
            raise CalibrateError(
                f"calibration run {run['id']} {run['status']}: {run.get('error') or 'no reason'}"
            )
        _say(_result_text(run["result"], row))
        return _maybe_apply(client, run, args, camera_id, input_fn)
    finally:
        client.close()


def _capture(source: Any, capture: BoardCapture, timeout: float) -> None:
    """Read `source` until the capture is done, the timeout, or Ctrl-C."""
    import cv2

    source.start()
    started = time.monotonic()
    last_hint = started
    try:
        while not capture.done:
            now = time.monotonic()
            if now - started > timeout:
                _say(f"Stopped after {timeout:g} s with {len(capture.views)} view(s).")
                break
            frame = source.frames.take(timeout=0.5)
            if frame is None:
                if source.finished.is_set():
                    _say(f"The stream ended with {len(capture.views)} view(s) kept.")
                    break
                continue
            image = frame.image
            if image is None and frame.jpeg is not None:
                image = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_COLOR)
            if image is None:
                continue
            if (image.shape[1], image.shape[0]) != capture.image_size:
                w, h = capture.image_size
                raise CalibrateError(
                    f"the stream's frames are {image.shape[1]}x{image.shape[0]} px but the "
                    f"registry's camera is {w}x{h}; set the camera's width and height (PATCH "
                    "/api/v1/cameras/{id}) or give the right --source"
                )
            view = capture.offer(image, frame.jpeg)
            if view is not None:
                x, y, s, k = view.params
                _say(
                    f"View {len(capture.views)}/{capture.max_views} kept: x {x:.2f} y {y:.2f} "
                    f"size {s:.2f} skew {k:.2f}\n{capture.coverage.render()}"
                )
            elif now - last_hint > 10.0:
                last_hint = now
                what = "seen but not new: move or tilt it" if capture.seen else "not seen"
                _say(f"  ... board {what} ({capture.frames} frames read)")
    except KeyboardInterrupt:
        _say(f"Interrupted with {len(capture.views)} view(s) kept.")
    finally:
        source.stop()
        source.join(5)
    if capture.done:
        _say("Coverage is enough: submitting.")


def _submit(client: Any, camera_id: int, args: argparse.Namespace, capture: BoardCapture) -> dict:
    import httpx

    files = [("files", (v.filename, v.data, v.content_type)) for v in capture.views]
    data = {
        "camera_id": str(camera_id),
        "chessboard": f"{args.board[0]}x{args.board[1]}",
        "square": repr(float(args.square)),
        "distortion": args.distortion,
    }
    try:
        response = client.request("POST", "/calibration-runs/upload", data=data, files=files)
    except httpx.TransportError as exc:
        raise CalibrateError(f"cannot reach the service at {client.api}: {exc}") from None
    if response.status_code != 202:
        raise CalibrateError(
            f"the service refused the calibration run ({response.status_code}): "
            f"{response.text[:300]}"
        )
    return response.json()


def _wait_for(client: Any, run_id: int, timeout: float = 600.0) -> dict:
    """Poll the run until it leaves queued/running."""
    import httpx

    deadline = time.monotonic() + timeout
    while True:
        try:
            response = client.request("GET", f"/calibration-runs/{run_id}")
        except httpx.TransportError as exc:
            raise CalibrateError(f"cannot reach the service at {client.api}: {exc}") from None
        if response.status_code != 200:
            raise CalibrateError(f"GET /calibration-runs/{run_id}: {response.status_code}")
        run = response.json()
        if run["status"] not in ("queued", "running"):
            return run
        if time.monotonic() > deadline:
            raise CalibrateError(
                f"calibration run {run_id} still {run['status']} after {timeout:g} s"
            )
        time.sleep(0.2)


def _result_text(result: dict, row: dict) -> str:
    K = np.asarray(result["K"], dtype=np.float64)
    lines = [
        f"Calibrated from {len(result.get('per_view_rms') or [])} views "
        f"({result['image_size'][0]}x{result['image_size'][1]} px):",
        f"  fx {K[0, 0]:.2f}  fy {K[1, 1]:.2f}  cx {K[0, 2]:.2f}  cy {K[1, 2]:.2f} px",
        "  dist (k1, k2, p1, p2, k3) [" + ", ".join(f"{v:.5g}" for v in result["dist"]) + "]",
        f"  RMS reprojection error {result['rms']:.4f} px",
    ]
    std = result.get("std_intrinsics") or {}
    if std:
        lines.append(
            "  standard deviations: " + ", ".join(f"{k} {v:.3g}" for k, v in std.items() if v > 0)
        )
    per_view = result.get("per_view_rms") or []
    if per_view:
        lines.append("  per-view RMS (px): " + " ".join(f"{v:.3f}" for v in per_view))
    for skipped in result.get("skipped") or []:
        lines.append(f"  not used: {skipped['filename']} ({skipped['reason']})")
    if row.get("K") is not None:
        old = np.asarray(row["K"], dtype=np.float64)
        lines.append(
            f"  the camera's present calibration: fx {old[0, 0]:.2f} fy {old[1, 1]:.2f} "
            f"cx {old[0, 2]:.2f} cy {old[1, 2]:.2f} px"
        )
    return "\n".join(lines)


def _maybe_apply(
    client: Any,
    run: dict,
    args: argparse.Namespace,
    camera_id: int,
    input_fn: Callable[[str], str],
) -> int:
    run_id = int(run["id"])
    apply = bool(args.apply)
    if not apply:
        if not sys.stdin.isatty():
            _say(
                f"Not applied (no terminal to ask; give --apply). Apply it later with "
                f"POST /api/v1/calibration-runs/{run_id}/apply."
            )
            return 0
        try:
            answer = input_fn(f"Apply this calibration to camera {args.camera!r}? [y/N] ")
        except EOFError:
            answer = ""
        apply = answer.strip().lower() in ("y", "yes")
    if not apply:
        _say(f"Not applied. Apply it later with POST /api/v1/calibration-runs/{run_id}/apply.")
        return 0
    response = client.request("POST", f"/calibration-runs/{run_id}/apply")
    if response.status_code != 200:
        raise CalibrateError(
            f"applying run {run_id} failed ({response.status_code}): {response.text[:300]}"
        )
    _say(f"Applied run {run_id} to camera {args.camera!r} (id {camera_id}).")
    return 0
