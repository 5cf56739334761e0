"""Recordings of a camera node: what it saw (frames, capture times) and what it detected.

`intspace node --record DIR` writes, for every frame its detector processed:

```
DIR/recording.json                 {"format": "intspace-recording", "version": 1,
                                    "created": ..., "cameras": [{"name", "folder",
                                    "camera_id", "width", "height", "detector"}]}
DIR/<folder>/index.jsonl           a line per frame: {"seq", "t" (capture time, Unix s on the
                                    service's clock), "received" (the node's clock), "file",
                                    "detections": [{"t", "pixel", "cov", "kind", "height"}]}
DIR/<folder>/000001.jpg ...        the frame: the stream's own JPEG bytes when it sent JPEG,
                                    else encoded at quality 95
```

A recording is also a source (`intspace node --source DIR --camera NAME`): `RecordingSource`
reads one camera's frames back with their capture times, at the pace they were captured or
(`--fast`) as fast as the detector takes them, without dropping any. The times are shifted by
one offset per recording so that its first frame is captured now: the service's tracker takes
frames only as they come (older ones are late), so a replay is tracked as the live session
was. Frames read as JPEG (the node's MJPEG reader: the service's streams, or `reader: mjpeg`)
come back byte for byte, so a replay through the same detectors posts the same detections (the
same pixels, kinds and covariances, at times shifted by that offset); frames decoded by OpenCV
(USB, RTSP, files, other HTTP) are kept re-encoded, and replay close to, not exactly as, live.

Folder names are made from the camera's name with anything but letters, digits, dot, dash and
underscore replaced, so no registry name reaches the file system as a path.
"""

from __future__ import annotations

import json
import logging
import re
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import cv2

from core.errors import InvalidInput
from server.node.frames import Frame, HandOver
from server.node.sources import Source

log = logging.getLogger("intspace.node")

RECORDING_FILE = "recording.json"
INDEX_FILE = "index.jsonl"
FORMAT = "intspace-recording"
VERSION = 1
# Quality 95, full-resolution chroma (4:4:4): a replay finds the coloured markers where the live
# run did (4:2:0 halves the chroma's resolution and moves their detected centres).
_JPEG_PARAMS = [
    cv2.IMWRITE_JPEG_QUALITY,
    95,
    cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
    cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444,
]
# A line of the index longer than this is not one of ours (a frame's detections are a few kB).
_MAX_LINE = 4 * 2**20


def is_recording(source: object) -> bool:
    """Return whether `source` names a folder holding a recording."""
    if not isinstance(source, str) or "://" in source:
        return False
    path = Path(source)
    return path.is_dir() and (path / RECORDING_FILE).is_file()


def folder_name(index: int, camera: str) -> str:
    """Return the folder of the `index`-th camera called `camera`: a safe file name."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", camera).strip("._") or "camera"
    return f"{index:02d}-{safe[:60]}"


# -- writing ---------------------------------------------------------------------------------------


class _CameraWriter:
    def __init__(self, folder: Path) -> None:
        folder.mkdir()
        self.folder = folder
        self.index = (folder / INDEX_FILE).open("a", encoding="utf-8")
        self.frames = 0
        self.lock = threading.Lock()


class Recorder:
    """Writes the frames a node's detectors processed, their capture times and detections.
    Thread-safe: each camera's detector thread calls `write`."""

    def __init__(self, root: Path, cameras: list[dict[str, Any]]) -> None:
        root = Path(root)
        if (root / RECORDING_FILE).exists():
            raise InvalidInput(f"{root} already holds a recording; record into a new folder")
        if root.exists() and (not root.is_dir() or any(root.iterdir())):
            raise InvalidInput(f"{root} exists and is not an empty folder; give a new folder")
        try:
            root.mkdir(parents=True, exist_ok=True)
            self._writers: dict[str, _CameraWriter] = {}
            entries = []
            for i, camera in enumerate(cameras):
                folder = folder_name(i, camera["name"])
                self._writers[camera["name"]] = _CameraWriter(root / folder)
                entries.append({**camera, "folder": folder})
            meta = {
                "format": FORMAT,
                "version": VERSION,
                "created": time.time(),
                "cameras": entries,
            }
            (root / RECORDING_FILE).write_text(json.dumps(meta, indent=2), encoding="utf-8")
        except OSError as exc:
            raise InvalidInput(f"cannot record into {root}: {exc.strerror or exc}") from None
        self.root = root
        self.failed: str | None = None

    def write(
        self, camera: str, frame: Frame, t: float, observations: list[dict[str, Any]]
    ) -> None:
        """Keep one processed frame of `camera`: its image, capture time `t` and the
        detections posted for it. A disk error stops the recording (said once), never the
        node."""
        writer = self._writers.get(camera)
        if writer is None or self.failed is not None:
            return
        data = frame.jpeg
        if data is None and frame.image is not None:
            ok, buf = cv2.imencode(".jpg", frame.image, _JPEG_PARAMS)
            data = buf.tobytes() if ok else None
        if data is None:
            return
        detections = [{k: v for k, v in o.items() if k != "camera_id"} for o in observations]
        with writer.lock:
            writer.frames += 1
            name = f"{writer.frames:06d}.jpg"
            line = {
                "seq": writer.frames,
                "t": t,
                "received": frame.received,
                "file": name,
                "detections": detections,
            }
            try:
                (writer.folder / name).write_bytes(data)
                writer.index.write(json.dumps(line) + "\n")
                writer.index.flush()
            except (OSError, ValueError) as exc:  # ValueError: written after close
                self.failed = f"{getattr(exc, 'strerror', None) or exc}"
                log.error("recording into %s stopped: %s", self.root, self.failed)

    def close(self) -> None:
        """Close the index files and say what was kept."""
        for writer in self._writers.values():
            with writer.lock:
                writer.index.close()
        total = sum(w.frames for w in self._writers.values())
        log.info("recorded %d frame(s) into %s", total, self.root)


# -- reading ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RecordedFrame:
    """One frame of a recording: sequence number, capture time, JPEG path, detections."""

    seq: int
    t: float
    path: Path
    detections: list[dict[str, Any]]


def recording_cameras(root: Path) -> list[dict[str, Any]]:
    """Return the cameras of the recording in `root` (name, folder, camera_id, width,
    height). Raises InvalidInput when `root` is not a recording this version reads."""
    try:
        meta = json.loads((Path(root) / RECORDING_FILE).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InvalidInput(f"{root} is not a readable recording: {exc}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InvalidInput(f"{root}/{RECORDING_FILE} is not an intspace recording")
    if meta.get("version") != VERSION:
        raise InvalidInput(
            f"{root} is a recording of version {meta.get('version')}; this node reads {VERSION}"
        )
    cameras = meta.get("cameras")
    if not isinstance(cameras, list) or not all(
        isinstance(c, dict) and isinstance(c.get("name"), str) for c in cameras
    ):
        raise InvalidInput(f"{root}/{RECORDING_FILE} lists no cameras")
    for camera in cameras:
        folder = str(camera.get("folder", ""))
        # The folder must be one of ours, inside the recording: never a path to elsewhere.
        if not re.fullmatch(r"\d{2}-[A-Za-z0-9._-]{1,60}", folder) or folder.startswith("."):
            raise InvalidInput(f"{root}/{RECORDING_FILE}: camera folder {folder!r} is not valid")
    return cameras


def recorded_frames(root: Path, camera: str) -> Iterator[RecordedFrame]:
    """Yield the frames of `camera` in the recording `root`, in recorded order. Raises
    InvalidInput when the recording has no such camera (naming those it has) or an index line
    is not valid."""
    cameras = recording_cameras(root)
    entry = next((c for c in cameras if c["name"] == camera), None)
    if entry is None:
        names = ", ".join(repr(c["name"]) for c in cameras)
        raise InvalidInput(f"the recording {root} has no camera {camera!r} (it has {names})")
    folder = Path(root) / entry["folder"]
    try:
        index = (folder / INDEX_FILE).open(encoding="utf-8")
    except OSError as exc:
        raise InvalidInput(f"cannot read {folder / INDEX_FILE}: {exc.strerror or exc}") from None
    with index:
        for number, line in enumerate(index, 1):
            if not line.strip():
                continue
            if len(line) > _MAX_LINE:
                raise InvalidInput(f"{folder / INDEX_FILE} line {number} is too long")
            try:
                item = json.loads(line)
                name = str(item["file"])
                t = float(item["t"])
                seq = int(item["seq"])
                detections = list(item.get("detections") or [])
            except (ValueError, KeyError, TypeError) as exc:
                if line.endswith("\n"):
                    raise InvalidInput(
                        f"{folder / INDEX_FILE} line {number} is not valid: {exc}"
                    ) from None
                return  # the last line cut short by a killed node: the recording ends there
            if not re.fullmatch(r"\d{6,}\.jpg", name):
                raise InvalidInput(f"{folder / INDEX_FILE} line {number}: bad file {name!r}")
            yield RecordedFrame(seq, t, folder / name, detections)


class _ReplayClock:
    """One time offset per recording and process: the first frame of any of its cameras is
    captured when the first of its sources starts."""

    _lock = threading.Lock()
    _offsets: ClassVar[dict[Path, float]] = {}

    @classmethod
    def offset(cls, root: Path, clock: Callable[[], float]) -> float:
        key = Path(root).resolve()
        with cls._lock:
            if key not in cls._offsets:
                first = min(
                    (
                        next(iter(recorded_frames(root, c["name"])), None)
                        for c in recording_cameras(root)
                    ),
                    key=lambda f: f.t if f is not None else float("inf"),
                    default=None,
                )
                cls._offsets[key] = clock() - first.t if first is not None else 0.0
            return cls._offsets[key]


class RecordingSource(Source):
    """One camera of a recording replayed: at its own pace (`realtime`, frames a slow detector
    did not take in time are dropped, as from a live camera) or as fast as the detector takes
    them (every frame). Ends with the recording."""

    def __init__(
        self,
        name: str,
        root: str | Path,
        *,
        realtime: bool = True,
        clock: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(name)
        self.root = Path(root)
        self.realtime = realtime
        self._clock = clock
        self._handover = HandOver()
        self.frames = self._handover
        # Fail at start-up, not in the reader thread: the camera must be in the recording.
        next(iter(recorded_frames(self.root, name)), None)

    def _read(self) -> Literal["ended", "retry"]:
        # One offset for every camera of the recording in this process, so the cameras keep
        # their relative timing; a frame is published when its shifted time comes.
        offset = _ReplayClock.offset(self.root, self._clock)
        try:
            for item in recorded_frames(self.root, self.name):
                if self._stop.is_set():
                    return "ended"
                try:
                    data = item.path.read_bytes()
                except OSError as exc:
                    self._problem(f"{item.path}: {exc.strerror or exc}; skipped")
                    continue
                if self.realtime:
                    self._stop.wait(max(0.0, item.t + offset - self._clock()))
                self._publish(item.t + offset, jpeg=data)
                if not self.realtime:
                    self._handover.wait_taken(self._seq, self._stop)
        except InvalidInput as exc:
            self._problem(str(exc))
        log.info("camera %s: the recording %s ended", self.name, self.root)
        return "ended"
