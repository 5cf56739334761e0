"""One camera node's threads: per camera a reader (sources) and a detector; one uploader; one
heartbeat, which also logs a summary every `summary_s` seconds. The detector calls
core.localization.detections.detect_frame, as the twin does, with the camera's people detector
(`people_detector`: the neural one for real cameras, background subtraction for the twin's)."""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal
from urllib.parse import urlsplit

import cv2
import httpx
import numpy as np
from numpy.typing import NDArray

from core.errors import IntspaceError, InvalidInput
from core.localization import NetworkCamera
from core.localization.appearance import box_appearance
from core.localization.boxes import BOX_SIDES
from core.localization.detect import MarkerDetectorConfig, PersonDetector
from core.localization.detections import FrameDetection, PeopleDetector, detect_frame
from core.localization.ssd_people import PersonBoxes, SsdConfig, SsdPeopleDetector
from server.delays import StageDelays
from server.node.client import NodeError, ServiceClient, Uploader
from server.node.config import (
    DEFAULT_SCORE_THRESHOLD,
    CameraConfig,
    NodeConfig,
)
from server.node.frame_upload import FrameUploads
from server.node.masks import apply_mask, polygon_mask
from server.node.record import Recorder, RecordingSource, is_recording, recording_cameras
from server.node.sources import (
    TIMEOUT_S,
    MjpegHttpSource,
    OpenCvSource,
    Source,
    SourceUnavailable,
    describe_source,
)

log = logging.getLogger("intspace.node")

HEARTBEAT_S = 1.0
# How often the node logs what it did (frames, detections posted, dropped, reconnects).
SUMMARY_S = 60.0
# Late frames (and a tenth of those posted) after which a fast replay is stopped as behind.
LATE_STOP = 5


def _origin(url: str) -> tuple[str, str, int | None]:
    parts = urlsplit(url)
    port = parts.port or {"http": 80, "https": 443}.get(parts.scheme)
    return parts.scheme, (parts.hostname or "").lower(), port


def make_source(
    camera: CameraConfig, api: str, token: str, clock: Callable[[], float] = time.time
) -> Source:
    """Return the source of `camera`: httpx MJPEG for the service's own streams (with the
    token: it is sent to the service's own address only) or when asked, OpenCV otherwise.
    `clock` is the service's (a file replayed fast is stamped from it). Raises InvalidInput
    for a live camera asked to play fast (realtime false): only a file or a recording can."""
    src = camera.source
    if is_recording(src):  # a folder written by `intspace node --record`
        return RecordingSource(camera.name, str(src), realtime=camera.realtime)
    is_file = isinstance(src, str) and "://" not in src
    if not camera.realtime and not is_file:
        raise InvalidInput(
            f"camera {camera.name!r}: {describe_source(src)} is a live camera; --fast (realtime: "
            "false) replays a video file or a recording as fast as it is detected in"
        )
    is_http = isinstance(src, str) and src.lower().startswith(("http://", "https://"))
    if is_http and camera.reader != "opencv":
        assert isinstance(src, str)
        ours = _origin(src) == _origin(api)
        if ours or camera.reader == "mjpeg":
            headers = {"Authorization": f"Bearer {token}"} if ours else {}
            return MjpegHttpSource(camera.name, src, headers)
    return OpenCvSource(
        camera.name, src, realtime=camera.realtime, clock=clock, source_fps=camera.source_fps
    )


def _is_service_stream(camera: CameraConfig, api: str) -> bool:
    src = camera.source
    return (
        isinstance(src, str)
        and src.lower().startswith(("http://", "https://"))
        and (_origin(src) == _origin(api))
    )


def detector_kind(camera: CameraConfig, api: str) -> Literal["dnn", "background"]:
    """Return the people detector `camera` runs: the configured one, or for "auto" the
    background model for the service's own streams (the twin's cameras: their people are
    coloured cylinders a detector trained on photographs does not know) and the neural
    detector for every other source (a real camera)."""
    if camera.detector != "auto":
        return camera.detector
    if is_recording(camera.source):
        # A replay runs the detector the recording was made with, so it posts what the live
        # node did; recordings that do not say were made with the background model.
        entry = next(
            (c for c in recording_cameras(Path(str(camera.source))) if c["name"] == camera.name),
            {},
        )
        return "dnn" if entry.get("detector") == "dnn" else "background"
    return "background" if _is_service_stream(camera, api) else "dnn"


def people_detector(
    camera: CameraConfig, kind: Literal["dnn", "background"], mask: NDArray[np.bool_] | None
) -> PersonDetector | PeopleDetector:
    """Return a new people detector of `kind` for `camera` (its settings and its mask)."""
    if kind == "background":
        return PersonDetector()
    threshold = camera.score_threshold
    if threshold is None:
        threshold = DEFAULT_SCORE_THRESHOLD
    config = SsdConfig(
        score_threshold=threshold,
        min_person_px=camera.min_person_px,
        flip=camera.flip,
        tile_px=camera.tile_px,
    )
    return SsdPeopleDetector(config=config, mask=mask)


def observation(camera_id: int, t: float, d: FrameDetection) -> dict[str, Any] | None:
    """Return one detection as POST /observations takes it; None when its covariance is not
    finite symmetric positive definite (the service would refuse the whole batch)."""
    cov = np.asarray(d.cov, dtype=np.float64)
    cov = 0.5 * (cov + cov.T)
    pixel = np.asarray(d.pixel, dtype=np.float64)
    finite = np.all(np.isfinite(cov)) and np.all(np.isfinite(pixel))
    if not finite or cov[0, 0] <= 0 or np.linalg.det(cov) <= 0:
        return None
    return {
        "camera_id": camera_id,
        "t": float(t),
        "pixel": [float(pixel[0]), float(pixel[1])],
        "cov": cov.tolist(),
        "kind": d.kind,
        "height": float(d.height),
    }


def box_observations(
    camera_id: int, t: float, found: PersonBoxes, looks: NDArray[np.float64]
) -> list[dict[str, Any]]:
    """Return a neural detector's boxes as POST /observations takes them: each person's box,
    score and cut sides, so the service measures its foot on the body's axis
    (core.localization.boxes.foot_on_axis, as for any detector's boxes), and its appearance
    `looks` (N, F) (core.localization.appearance.box_appearance of the frame), which the
    tracker uses to tell people side by side apart; a box whose bottom is cut is stored there
    but gives no floor position."""
    out = []
    for box, score, cut, look in zip(found.boxes, found.scores, found.cut, looks, strict=True):
        out.append(
            {
                "camera_id": camera_id,
                "t": float(t),
                "box": [float(v) for v in box],
                "score": float(score),
                "cut": [side for side, c in zip(BOX_SIDES, cut, strict=True) if c],
                "appearance": [round(float(v), 6) for v in look],
                "kind": "person",
            }
        )
    return out


@dataclass
class CameraRun:
    """A camera being read and detected in."""

    config: CameraConfig
    camera_id: int
    size: tuple[int, int]
    network: NetworkCamera | None  # None: not placed yet, frames are uploaded, nothing detected
    source: Source
    mask: NDArray[np.bool_] | None
    people: PersonDetector | PeopleDetector = field(default_factory=PersonDetector)
    detector: Literal["dnn", "background"] = "background"
    detected: int = 0
    detections: int = 0
    learned: int = 0
    problem: str | None = None


class Node:
    """The cameras of a configuration, read, detected in and reported until stopped."""

    def __init__(
        self, config: NodeConfig, api: str, token: str, *, summary_s: float = SUMMARY_S
    ) -> None:
        self.config = config
        self.summary_s = float(summary_s)
        self.api = api
        self.client = ServiceClient(api, token)
        self.uploader = Uploader(self.client)
        self.frames = FrameUploads(self.client)
        self._token = token
        self._marker = MarkerDetectorConfig(
            colour=config.marker.colour, radius=config.marker.radius
        )
        self.cameras: list[CameraRun] = []
        self.stop_event = threading.Event()
        self._threads: list[threading.Thread] = []
        # --record DIR: keeps each processed frame.
        self.recorder: Recorder | None = None
        # Why the node stopped before its sources ended (a fast replay fell behind), if so;
        # the late frames already said.
        self.failure: str | None = None
        self._late_said = 0
        # Per processed frame: capture to its arrival here (the stream), waiting for the
        # detector, decoding and detecting (s). The uploader has the rest, to the service.
        self.delays = StageDelays(("capture to received", "waiting", "decode and detect"))

    def prepare(self) -> None:
        """Fetch each camera's registry row and calibration, then open its source (a camera
        without a calibration only has its frames uploaded, for placing it). Raises NodeError
        for an unknown camera or a bad mask, InvalidInput for a bad source setting,
        SourceUnavailable for a source that does not open."""
        try:
            for cam in self.config.cameras:
                source = make_source(cam, self.api, self._token, self._service_time)
                self.cameras.append(self._camera_run(cam, source))
            for run in self.cameras:
                try:
                    run.source.check()
                except SourceUnavailable as exc:
                    raise SourceUnavailable(f"camera {run.config.name!r}: {exc}") from None
        except BaseException:
            for run in self.cameras:
                run.source.stop()
            raise

    def record(self, root: Path) -> None:
        """Keep each frame the prepared cameras' detectors process, with its capture time and
        detections, in the new folder `root` (a recording). Raises InvalidInput when `root`
        exists and is not empty, or cannot be written."""
        cameras = [
            {
                "name": run.config.name,
                "camera_id": run.camera_id,
                "width": run.size[0],
                "height": run.size[1],
                "detector": run.detector,
            }
            for run in self.cameras
        ]
        self.recorder = Recorder(root, cameras)
        log.info("recording %d camera(s) into %s", len(cameras), root)

    def _service_time(self) -> float:
        return time.time() + self.client.offset

    def _camera_run(self, cam: CameraConfig, source: Source) -> CameraRun:
        row = self.client.camera(cam.name, self.config.space)
        size = (int(row["width"]), int(row["height"]))
        network: NetworkCamera | None = None
        try:
            if row.get("K") is not None and row.get("T_world_camera") is not None:
                network = NetworkCamera.from_pose(
                    row["K"], row.get("dist"), row["T_world_camera"], size, cam.name
                )
            mask = polygon_mask(size, cam.masks)
            kind = detector_kind(cam, self.api)
            people = people_detector(cam, kind, mask)
        except IntspaceError as exc:
            raise NodeError(f"camera {cam.name!r}: {exc}") from exc
        if network is None:
            # Its frames let the dashboard place it; detections wait for its pose.
            log.warning(
                "camera %r (id %s) has no intrinsics or pose in the registry: uploading its "
                "frames only; place it (the dashboard's camera page, or POST "
                "/api/v1/cameras/%s/placement) and restart the node to detect",
                cam.name,
                row["id"],
                row["id"],
            )
        return CameraRun(cam, int(row["id"]), size, network, source, mask, people, kind)

    def run(self) -> int:
        """Run until `stop_event` is set or every source ended; return the exit code (0, or 1
        when a fast replay fell behind its clip or a camera's detection failed)."""
        self._announce_replays()
        for run in self.cameras:
            log.info("camera %s: people by the %s detector", run.config.name, run.detector)
        self.uploader.start()
        for run in self.cameras:
            run.source.start()
            thread = threading.Thread(
                target=self._detect_loop, args=(run,), name=f"detect-{run.config.name}"
            )
            thread.start()
            self._threads.append(thread)
            log.info(
                "camera %s (id %d): reading %s",
                run.config.name,
                run.camera_id,
                describe_source(run.config.source),
            )
        beat = threading.Thread(target=self._heartbeat_loop, name="heartbeat", daemon=True)
        beat.start()
        try:
            while not self.stop_event.is_set():
                if all(run.source.finished.is_set() for run in self.cameras):
                    break
                self.stop_event.wait(0.2)
        finally:
            if not self.stop_event.is_set():
                # Every source ended (video files): the detectors finish their last frames.
                for thread in self._threads:
                    thread.join(30)
            self.stop_event.set()
            for run in self.cameras:
                run.source.stop()
            for thread in self._threads:
                thread.join(5)
            for run in self.cameras:
                # A reader inside OpenCV's read (up to its 2 s timeout) must not be there when
                # the interpreter exits: the process would abort instead of exiting.
                run.source.join(TIMEOUT_S + 1.0)
            self.uploader.stop()
            self._heartbeat()
            self._check_replays()
            self._summary("at the end")
            log.info(
                "posted %d detection(s) and %d empty frame(s); %d camera frame(s) came too late "
                "to be tracked",
                self.uploader.posted,
                self.uploader.posted_empty,
                self.uploader.late,
            )
            if len(self.delays):
                # The capture times are the service's clock; the node's own are corrected by
                # the offset it measured, whose uncertainty bounds these delays' accuracy.
                log.info(
                    "frames: %s (clock offset %+.3f s, known to +-%.3f s)",
                    self.delays.describe(),
                    self.client.offset,
                    self.client.clock.uncertainty,
                )
                log.info("uploads: %s", self.uploader.delays.describe())
            if self.uploader.dropped:
                log.warning(
                    "%d detection(s) dropped while the service was unreachable",
                    self.uploader.dropped,
                )
            if self.recorder is not None:
                self.recorder.close()
            self.client.close()
        if self.failure is not None:
            log.error("stopped: %s", self.failure)
            return 1
        return 0

    def _detect_loop(self, run: CameraRun) -> None:
        """Detect in `run`'s frames until stopped or its source ends. An exception stops the
        node (exit code 1, said in one line): a camera whose frames nobody detects in would be
        read on and reported healthy while it posts nothing."""
        try:
            self._detect_frames(run)
        except Exception as exc:
            log.debug("camera %s: detection failed", run.config.name, exc_info=True)
            if self.failure is None:
                self.failure = (
                    f"camera {run.config.name}: detecting in its frames failed "
                    f"({run.detector} detector, after {run.detected} frame(s)): "
                    f"{type(exc).__name__}: {exc}"
                )
            self.stop_event.set()

    def _detect_frames(self, run: CameraRun) -> None:
        period = 1.0 / run.config.fps if run.config.fps else 0.0
        next_time = time.monotonic()
        height = self.config.marker.height
        while not self.stop_event.is_set():
            frame = run.source.frames.take(timeout=0.5)
            if frame is None:
                if run.source.frames.closed:
                    return
                continue
            taken = time.time()
            image: Any = frame.image
            if image is None and frame.jpeg is not None:
                image = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_COLOR)
            if image is None:
                self._problem(run, "a frame did not decode as an image")
                continue
            if (image.shape[1], image.shape[0]) != run.size:
                self._problem(
                    run,
                    f"frames are {image.shape[1]}x{image.shape[0]} px but the registry's "
                    f"calibration is for {run.size[0]}x{run.size[1]}: skipping them",
                )
                continue
            self.frames.offer(run.camera_id, None if frame.jpeg else image, frame.jpeg)
            if run.network is None:
                continue
            image = apply_mask(image, run.mask)
            t = frame.t
            if t is None:
                local = frame.captured if frame.captured is not None else frame.received
                t = local + self.client.offset
                if frame.captured is not None and run.detected == 0:
                    # A file's frames are timed from its start: say when that was, so what the
                    # service tracked can be laid beside the file (frame seq - 1 at t).
                    log.info(
                        "camera %s: frame %d of the file captured at %.6f (service clock)",
                        run.config.name,
                        frame.seq - 1,
                        t,
                    )
            # Only a background model learns; a neural detector detects from the first frame.
            learning = False
            if isinstance(run.people, PersonDetector) and (
                run.learned < self.config.background_frames
            ):
                run.people.learn(image)
                run.learned += 1
                learning = True
            boxes = isinstance(run.people, SsdPeopleDetector)
            found = detect_frame(
                image,
                marker=self._marker,
                marker_height=height,
                people=None if learning or boxes else run.people,
                camera=run.network,
            )
            obs = [observation(run.camera_id, t, d) for d in found]
            kept = [o for o in obs if o is not None]
            if isinstance(run.people, SsdPeopleDetector):
                # The boxes go to the service whole: it measures their feet on the body's
                # axis with the camera's geometry and floor plan, as for any detector's boxes.
                boxes_found = run.people.detect_boxes(image)
                looks = box_appearance(image, boxes_found.boxes)
                kept += box_observations(run.camera_id, t, boxes_found, looks)
            if kept:
                self.uploader.push(kept)
                run.detections += len(kept)
            else:
                # Nothing seen is news too: the tracker need not wait for this camera up to t.
                self.uploader.push_empty(run.camera_id, t)
            pushed = time.time()
            self.delays.add(
                frame.received + self.client.offset - t, taken - frame.received, pushed - taken
            )
            if self.recorder is not None:
                self.recorder.write(run.config.name, frame, t, kept)
            run.detected += 1
            if period:
                next_time = max(next_time + period, time.monotonic())
                self.stop_event.wait(max(0.0, next_time - time.monotonic()))

    def _problem(self, run: CameraRun, message: str) -> None:
        if message != run.problem:
            log.warning("camera %s: %s", run.config.name, message)
        run.problem = message

    def _heartbeat_loop(self) -> None:
        next_summary = time.monotonic() + self.summary_s
        while not self.stop_event.wait(HEARTBEAT_S):
            self._heartbeat()
            self._check_replays()
            if self.summary_s > 0 and time.monotonic() >= next_summary:
                next_summary += self.summary_s
                self._summary("so far")

    def _announce_replays(self) -> None:
        """Tell the service's tracker, before a fast replay starts, that its cameras saw nothing
        up to now (an empty frame each): its first frames then find the space's tracker made
        and the service warm, instead of waiting behind the first post of a cold service
        (above a second on a loaded machine) and reaching the tracker too late."""
        fast = [run.camera_id for run in self.cameras if not run.config.realtime]
        if not fast:
            return
        now = self._service_time()
        body = {"observations": [], "empty_frames": [{"camera_id": c, "t": now} for c in fast]}
        with contextlib.suppress(httpx.TransportError):
            self.client.request("POST", "/observations", json=body)

    def _check_replays(self) -> None:
        """Say when a fast replay's frames reach the service too late to be tracked, and stop
        the node once they keep doing so.

        A fast replay stamps its frames with the clip's own timing from when it started; a
        detector slower than the clip falls further behind those times with every frame, and
        the service's tracker refuses frames older than its window (INTSPACE_TRACKER_LATENCY_S)
        as late. Then every frame tracked with the clip's timing is impossible: once a tenth of
        the frames posted (and at least LATE_STOP of them) were late, the node says so and
        stops, rather than post frames the tracker throws away. A late frame now and then (the
        machine busy for a moment) is said, and the replay goes on."""
        fast = [run for run in self.cameras if not run.config.realtime]
        late = self.uploader.late
        if not fast or not late or self.failure is not None:
            return
        posted = sum(run.detected for run in self.cameras)  # camera frames sent, about
        rates = []
        for run in fast:
            clip = getattr(run.source, "fps", 0.0)
            rates.append(
                f"camera {run.config.name}: {run.detected} frame(s) detected in at "
                f"{run.source.stats.fps(time.time()):.1f}/s"
                + (f", the clip has {clip:g}/s" if clip else "")
            )
        said = (
            f"the service refused {late} of {posted} frame(s) of a fast replay as too late to be "
            f"tracked ({'; '.join(rates)})"
        )
        if late >= LATE_STOP and late * 10 >= posted:
            self.failure = (
                f"a fast replay fell behind its clip's own timing: {said}. The detector is "
                "slower than the clip on this machine: replay at the clip's own pace (without "
                "--fast: frames the detector cannot take are dropped, as from a live camera), "
                "or give the service a longer INTSPACE_TRACKER_LATENCY_S"
            )
            self.stop_event.set()
        elif late > self._late_said:
            log.warning("%s; going on", said)
            self._late_said = late

    def _summary(self, when: str) -> None:
        """Log, per camera, what the node did since it started: frames read, detected in and
        dropped (replaced by a newer one before the detector took them), reconnects; and what
        was posted."""
        for run in self.cameras:
            stats = run.source.stats
            log.info(
                "summary %s: camera %s: %d frame(s) read (%.1f/s now), %d detected in, %d "
                "dropped, %d detection(s); %d stall(s), %d reconnect(s)",
                when,
                run.config.name,
                stats.frames,
                stats.fps(time.time()),
                run.detected,
                run.source.frames.dropped,
                run.detections,
                stats.stalls,
                stats.reconnects,
            )
        log.info(
            "summary %s: %d detection(s) and %d empty frame(s) posted, %d waiting, %d dropped "
            "while the service was unreachable, %d frame(s) too late to be tracked",
            when,
            self.uploader.posted,
            self.uploader.posted_empty,
            self.uploader.pending,
            self.uploader.dropped,
            self.uploader.late,
        )

    def _heartbeat(self) -> None:
        self.frames.send_due()
        now = time.time()
        offset = self.client.offset
        for run in self.cameras:
            stats = run.source.stats
            last = stats.last_t
            if last is None and stats.last_received is not None:
                last = stats.last_received + offset
            body = {
                "fps": round(stats.fps(now), 3),
                "stalls": stats.stalls,
                "reconnects": stats.reconnects,
                "dropped": run.source.frames.dropped,
                "dropped_detections": self.uploader.dropped,
                "clock_offset_s": offset,
                "last_frame_t": last,
            }
            self.client.heartbeat(run.camera_id, body)
