"""Real footage: PETS 2009 S2.L1 View_001 through the product, as a user runs it.

Run from the repository root:  python -m bench.bench_pets [--frames 400]

Two parts (spec 08, "Real footage"):

1. The people detectors on the clip: precision and recall of their boxes at IoU 0.5 against
   the ground truth's boxes (frames 1-400; a box on a conf 0 person is neither a hit nor a false
   positive), and frames per second per core (CPU time of one thread, so other load on the
   machine does not count) at 768 x 576 and at 640 x 480 (the clip resized).
2. Tracking on the floor: the camera is placed from the ground truth's floor points (the foot
   of each box and its world position: a pinhole with square pixels and a centred principal
   point, focal length and pose by least squares; the product's placement endpoint will do
   this), registered in a running `intspace serve`, and a plain
   `intspace node --source VIDEO --camera pets --source-fps 7` plays the clip to it in real
   time with an ingest token. The service's targets and stored tracks (GET /targets,
   GET /targets/{id}/track) are scored with motmetrics on the floor (Euclidean, 1 m) against
   the ground truth's world_x, world_y: at each ground-truth frame each target answers with
   its latest track point unless that is older than the tracker's coast_after (0.5 s): what
   GET /targets shows a user then.

The video is Debian's opencv-doc `examples/data/vtest.avi` (INTSPACE_PETS_VIDEO, default
/var/cache/intspace/vtest.avi; .ci/run installs it); the ground truth is
../shared/data/pets2009-s2l1/gt-frames-001-400.txt (INTSPACE_PETS_GT overrides).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import re  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import cv2  # noqa: E402
import httpx  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from scipy.optimize import linear_sum_assignment, minimize_scalar  # noqa: E402

from tests.support.service import WITHOUT_TWIN, clean_env, running_service  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
VIDEO_ENV = "INTSPACE_PETS_VIDEO"
DEFAULT_VIDEO = "/var/cache/intspace/vtest.avi"
GT_ENV = "INTSPACE_PETS_GT"
DEFAULT_GT = REPO.parent / "shared" / "data" / "pets2009-s2l1" / "gt-frames-001-400.txt"
SIZE = (768, 576)
SOURCE_FPS = 7.0  # the footage's capture rate (its container says 10)
MATCH_M = 1.0  # motmetrics' gate on the floor
IOU = 0.5  # a detector's box is a hit at this IoU with a ground-truth box (PASCAL)
CAMERA = "pets_view_001"
# spec 08's goals on the footage
# Capture times are rounded to microseconds in the node's log and the database.
EPS_S = 1e-3
GOAL_MOTA = 0.75
GOAL_IDF1 = 0.70
GOAL_FPS = 7.0

Array = NDArray[np.float64]


def video_path() -> Path:
    """Return where the clip is expected (INTSPACE_PETS_VIDEO or the default)."""
    return Path(os.environ.get(VIDEO_ENV, DEFAULT_VIDEO))


def truth_path() -> Path:
    """Return where the ground truth is expected (INTSPACE_PETS_GT or ../shared/data)."""
    return Path(os.environ.get(GT_ENV, str(DEFAULT_GT)))


@dataclass(frozen=True)
class Truth:
    """The ground truth's rows: frame (1-based), id, box (x0, y0, x1, y1) px, conf, world
    (x, y) m."""

    frame: NDArray[np.int64]
    ident: NDArray[np.int64]
    box: Array
    conf: NDArray[np.int64]
    world: Array

    def rows(self, frame: int) -> NDArray[np.bool_]:
        return self.frame == frame


def load_truth(path: Path | None = None) -> Truth:
    """Return the MOTChallenge rows of `path` (frame, id, left, top, width, height, conf,
    world_x, world_y, world_z)."""
    a = np.loadtxt(path or truth_path(), delimiter=",", ndmin=2)
    box = np.column_stack([a[:, 2], a[:, 3], a[:, 2] + a[:, 4], a[:, 3] + a[:, 5]])
    return Truth(
        frame=a[:, 0].astype(np.int64),
        ident=a[:, 1].astype(np.int64),
        box=box,
        conf=a[:, 6].astype(np.int64),
        world=a[:, 7:9].copy(),
    )


def read_frames(path: Path, count: int) -> list[NDArray[np.uint8]]:
    """Return the first `count` frames of the video (BGR)."""
    cap = cv2.VideoCapture(str(path))
    frames = []
    try:
        while len(frames) < count:
            ok, image = cap.read()
            if not ok:
                break
            frames.append(image)
    finally:
        cap.release()
    if not frames:
        raise SystemExit(f"cannot read {path}")
    return frames


# ---------------------------------------------------------------------------------------------
# Placing the camera from floor points (what the placement endpoint will do)


@dataclass(frozen=True)
class Placement:
    """A pinhole camera placed from floor points: K, T_world_camera and the reprojection
    errors (px) of the points."""

    K: Array
    T_world_camera: Array
    errors: Array


def place_camera(truth: Truth, size: tuple[int, int] = SIZE) -> Placement:
    """Return the camera that best reprojects the ground truth's floor points (the bottom
    centre of each counted box, at its world position): square pixels, principal point at the
    image centre, no distortion; the focal length by a bounded scalar search around
    cv2.solvePnP's pose (iterative, least squares)."""
    keep = truth.conf == 1
    pixels = np.column_stack(
        [0.5 * (truth.box[keep, 0] + truth.box[keep, 2]), truth.box[keep, 3]]
    ).astype(np.float64)
    world = np.column_stack([truth.world[keep], np.zeros(int(keep.sum()))]).astype(np.float64)
    cx, cy = (size[0] - 1) / 2.0, (size[1] - 1) / 2.0

    def solve(f: float) -> tuple[Array, Array, Array]:
        K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
        ok, rvec, tvec = cv2.solvePnP(world, pixels, K, None, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise RuntimeError("solvePnP failed on the floor points")
        projected, _ = cv2.projectPoints(world, rvec, tvec, K, None)
        err = np.linalg.norm(projected.reshape(-1, 2) - pixels, axis=1)
        return K, np.hstack([rvec.ravel(), tvec.ravel()]), err

    best = minimize_scalar(
        lambda f: float(np.mean(solve(f)[2] ** 2)), bounds=(300.0, 5000.0), method="bounded"
    )
    K, pose, err = solve(float(best.x))
    R, _ = cv2.Rodrigues(pose[:3])
    T_camera_world = np.eye(4)
    T_camera_world[:3, :3] = R
    T_camera_world[:3, 3] = pose[3:]
    return Placement(K=K, T_world_camera=np.linalg.inv(T_camera_world), errors=err)


# ---------------------------------------------------------------------------------------------
# Part 1: the detectors' boxes


@dataclass(frozen=True)
class BoxScore:
    """Hits, false positives and misses of a detector's boxes at IoU 0.5."""

    hits: int
    false_positives: int
    misses: int

    @property
    def precision(self) -> float:
        return self.hits / max(self.hits + self.false_positives, 1)

    @property
    def recall(self) -> float:
        return self.hits / max(self.hits + self.misses, 1)


def _iou(a: Array, b: Array) -> Array:
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    inter = np.maximum(w, 0) * np.maximum(h, 0)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return inter / (area_a[:, None] + area_b[None, :] - inter)


def score_boxes(truth: Truth, boxes_by_frame: dict[int, Array]) -> BoxScore:
    """Return the hits, false positives and misses of the boxes (frame (1-based) -> (N, 4)
    x0, y0, x1, y1) against the truth's boxes of those frames, one-to-one (Hungarian on IoU),
    a hit at IoU >= 0.5; a box matched to a conf 0 person counts neither way."""
    hits = fps = misses = 0
    for frame, boxes in boxes_by_frame.items():
        rows = truth.rows(frame)
        gt, conf = truth.box[rows], truth.conf[rows]
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        matched_gt = np.zeros(0, dtype=np.int64)
        matched_b = np.zeros(0, dtype=np.int64)
        if len(gt) and len(b):
            iou = _iou(gt, b)
            r, c = linear_sum_assignment(-iou)
            ok = iou[r, c] >= IOU
            matched_gt, matched_b = r[ok], c[ok]
        counted = conf[matched_gt] == 1
        hits += int(counted.sum())
        misses += int((conf == 1).sum() - counted.sum())
        fps += len(b) - len(matched_b)
    return BoxScore(hits, fps, misses)


@dataclass(frozen=True)
class DetectorResult:
    name: str
    score: BoxScore
    fps_by_size: dict[tuple[int, int], float]


def measure_detectors(frames: list[NDArray[np.uint8]], truth: Truth) -> list[DetectorResult]:
    """Return each detector's box score on the frames (frame k is ground-truth frame k + 1)
    and its frames per second per core (thread CPU time) at 768 x 576 and 640 x 480."""
    from core.localization.detect import PersonDetector
    from core.localization.ssd_people import (
        FLOAT_MODEL,
        SsdConfig,
        SsdPeopleDetector,
        default_model_path,
    )

    cv2.setNumThreads(1)
    results = []

    def timed(detect, images) -> float:
        start = time.thread_time()
        for image in images:
            detect(image)
        return len(images) / (time.thread_time() - start)

    # dnn: the node's default (the 8-bit model over 230 px tiles, each enlarged 1.3 times to the
    # model's input), the float model it was quantized from on the same tiles, the camera's own
    # resolution (300 px tiles, the model's input, as the node cut frames before), a costlier
    # candidate (each tile detected in its mirror image too, the two views merged), and the
    # whole frame in one pass (the model shrinks it to 300 x 300).
    native = SsdConfig(tile_px=300, tile_overlap_px=64, row_overlap_px=64)
    candidates = [
        ("dnn (8-bit, 230 px tiles)", None, SsdConfig()),
        ("dnn, float model, 230 px tiles", FLOAT_MODEL, SsdConfig()),
        ("dnn, 8-bit, 300 px tiles", None, native),
        ("dnn, 230 px tiles and mirror images", None, SsdConfig(flip=True)),
        ("dnn, whole frame", None, SsdConfig(tile_px=max(SIZE))),
    ]
    for name, model_name, config in candidates:
        model = None if model_name is None else default_model_path(model_name)
        dnn = SsdPeopleDetector(model, config=config)
        boxes = {k + 1: dnn.detect_boxes(image).boxes for k, image in enumerate(frames)}
        speed = {}
        for size in (SIZE, (640, 480)):
            images = [cv2.resize(f, size, interpolation=cv2.INTER_AREA) for f in frames[:40]]
            speed[size] = timed(SsdPeopleDetector(model, config=config).detect_boxes, images)
        results.append(DetectorResult(name, score_boxes(truth, boxes), speed))

    # background: the node's learning (its first 30 frames teach the model), then the blobs.
    learn = 30
    model = PersonDetector()
    boxes = {}
    for k, image in enumerate(frames):
        if k < learn:
            model.learn(image)
            continue
        found = model.detect(image)
        boxes[k + 1] = np.array(
            [[x, y, x + w, y + h] for x, y, w, h in (p.bbox for p in found)], dtype=np.float64
        ).reshape(-1, 4)
    speed = {}
    for size in (SIZE, (640, 480)):
        images = [cv2.resize(f, size, interpolation=cv2.INTER_AREA) for f in frames[:80]]
        m = PersonDetector()
        for image in images[:learn]:
            m.learn(image)
        speed[size] = timed(m.detect, images[learn:])
    results.append(DetectorResult("background (MOG2 blobs)", score_boxes(truth, boxes), speed))
    return results


# ---------------------------------------------------------------------------------------------
# Part 2: the node and the service


@dataclass(frozen=True)
class TrackingRun:
    """What the service tracked from the node's detections: each person target's points
    (t, x, y), the number of robot targets, the capture time of the file's frame 0 and the
    node's log."""

    points: dict[int, Array]
    robot_targets: int
    t0: float
    node_log: str


def clip_video(source: Path, frames: int, out: Path) -> Path:
    """Write the first `frames` frames of `source` losslessly (FFV1) to `out`."""
    images = read_frames(source, frames)
    h, w = images[0].shape[:2]
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"FFV1"), 10.0, (w, h))
    if not writer.isOpened():
        raise RuntimeError("OpenCV cannot write FFV1 video here")
    for image in images:
        writer.write(image)
    writer.release()
    check = read_frames(out, 1)[0]
    if not np.array_equal(check, images[0]):
        raise RuntimeError("the FFV1 copy of the clip is not lossless")
    return out


def track_through_service(
    video: Path,
    placement: Placement,
    workdir: Path,
    posted: list[Any] | None = None,
    node_args: tuple[str, ...] = (),
) -> TrackingRun:
    """Start `intspace serve`, register and place the camera, play `video` through
    `intspace node --source VIDEO --camera NAME --source-fps 7` with an ingest token, and
    return the service's tracks. With `posted` (each frame's PersonBoxes and their
    appearances, detected beforehand), post every frame's boxes one frame each 1/7 s
    instead, as the node posts them: the node's figures on a machine that would keep up with
    every frame."""
    admin = "pets-bench-admin-token"
    with running_service(
        workdir / "data", token=admin, env=WITHOUT_TWIN, log_path=workdir / "serve.log"
    ) as service:
        http = httpx.Client(base_url=service.api, headers=service.headers, timeout=10)
        try:
            return _track(http, service.api, video, placement, workdir, posted, node_args)
        finally:
            http.close()


def _track(
    http: httpx.Client,
    api: str,
    video: Path,
    placement: Placement,
    workdir: Path,
    posted: list[Any] | None,
    node_args: tuple[str, ...],
) -> TrackingRun:
    """Register and place the camera in the running service, play or post the clip, and
    return the service's tracks (track_through_service)."""
    space = http.post("/spaces", json={"name": "PETS 2009 campus"})
    assert space.status_code == 201, space.text
    camera = http.post(
        "/cameras",
        json={
            "name": CAMERA,
            "space_id": space.json()["id"],
            "width": SIZE[0],
            "height": SIZE[1],
            "K": placement.K.tolist(),
            "dist": [0.0] * 5,
            "T_world_camera": placement.T_world_camera.tolist(),
        },
    )
    assert camera.status_code == 201, camera.text
    camera_id = camera.json()["id"]
    token = http.post(
        "/tokens", json={"name": "pets node", "scopes": ["ingest"], "camera_ids": [camera_id]}
    )
    assert token.status_code == 201, token.text
    ingest = token.json()["token"]
    if posted is None:
        t0, text = _play_node(video, api, ingest, workdir, node_args)
    else:
        t0, text = _post_frames(posted, api, ingest, camera_id)
    # The tracker releases the posted frames after its reorder window (1 s) and writes
    # tracks twice a second: wait that long, then until the stored tracks stop growing.
    time.sleep(2.0)
    points = _stored_tracks(http)
    for _ in range(20):
        time.sleep(0.5)
        again = _stored_tracks(http)
        if sum(len(p) for p in again.values()) == sum(len(p) for p in points.values()):
            break
        points = again
    robots = http.get("/targets", params={"state": "all", "kind": "robot"}).json()["total"]
    return TrackingRun(points=points, robot_targets=int(robots), t0=t0, node_log=text)


def _play_node(
    video: Path, api: str, token: str, workdir: Path, node_args: tuple[str, ...] = ()
) -> tuple[float, str]:
    """Run `intspace node` on `video` (with `node_args`) to its end; return the capture time
    of the file's frame 0 (what the node said) and the node's log."""
    node_env = clean_env()
    node_env["INTSPACE_TOKEN"] = token
    node_log = workdir / "node.log"
    with node_log.open("w") as log:
        node = subprocess.run(
            [
                sys.executable,
                "-m",
                "server.cli",
                "node",
                "--source",
                str(video),
                "--camera",
                CAMERA,
                "--source-fps",
                f"{SOURCE_FPS:g}",
                "--api",
                api,
                *node_args,
            ],
            cwd=REPO,
            env=node_env,
            stdout=subprocess.DEVNULL,
            stderr=log,
            timeout=1800,
        )
    text = node_log.read_text()
    if node.returncode != 0:
        raise RuntimeError(f"intspace node exited {node.returncode}:\n{text}")
    found = re.search(r"frame (\d+) of the file captured at ([0-9.]+)", text)
    if found is None:
        raise RuntimeError(f"the node did not say when its file's frames were captured:{text}")
    return float(found.group(2)) - int(found.group(1)) / SOURCE_FPS, text


def _post_frames(posted: list[Any], api: str, token: str, camera_id: int) -> tuple[float, str]:
    """POST /observations each frame's boxes (the node's own box_observations) at its capture
    time, frame k at t0 + k / 7 s on the service's clock (this machine's); return t0 and a
    line like the node's."""
    from server.node.runner import box_observations

    t0 = time.time() + 1.0
    detections = empty = 0
    with httpx.Client(headers={"Authorization": f"Bearer {token}"}, timeout=30) as client:
        for k, (found, looks) in enumerate(posted):
            t = t0 + k / SOURCE_FPS
            time.sleep(max(0.0, t - time.time()))
            obs = box_observations(camera_id, t, found, looks)
            body: dict[str, Any] = {"observations": obs}
            if not obs:
                body = {"empty_frames": [{"camera_id": camera_id, "t": t}]}
            answer = client.post(f"{api}/observations", json=body)
            if answer.status_code != 200:
                raise RuntimeError(f"POST /observations: {answer.status_code} {answer.text}")
            detections += len(obs)
            empty += not obs
    return t0, f"posted {detections} detection(s) and {empty} empty frame(s)"


def _stored_tracks(http: httpx.Client) -> dict[int, Array]:
    """Return every person target's stored track points (t, x, y), oldest first."""
    targets, offset = [], 0
    while True:
        page = http.get(
            "/targets", params={"state": "all", "kind": "person", "limit": 100, "offset": offset}
        ).json()
        targets += page["items"]
        offset += len(page["items"])
        if offset >= page["total"] or not page["items"]:
            break
    out = {}
    for target in targets:
        points: list[list[float]] = []
        until = None
        while True:
            params: dict[str, float | int] = {"limit": 1000}
            if until is not None:
                params["until"] = until
            chunk = http.get(f"/targets/{target['id']}/track", params=params).json()["points"]
            points = [[p["t"], *p["xy"]] for p in chunk] + points
            if len(chunk) < 1000:
                break
            until = chunk[0]["t"]
        if points:
            out[int(target["id"])] = np.asarray(points, dtype=np.float64)
    return out


@dataclass(frozen=True)
class TrackScore:
    mota: float
    idf1: float
    switches: int
    false_positives: int
    misses: int
    matches: int
    frames: int


def score_tracking(
    run: TrackingRun, truth: Truth, frames: int, hold_s: float | None = None, first: int = 1
) -> TrackScore:
    """Return the MOT metrics of the run on ground-truth frames first..frames: at frame f (captured
    at t0 + (f - 1) / 7) each target answers with its latest track point at most `hold_s` old
    (default: the tracker's coast_after, 0.5 s: until then GET /targets shows the target as
    confirmed at that point, which is what a user sees); hypotheses within 1 m of a conf 0
    person are first matched to them (Hungarian) and dropped, neither a miss nor a false
    positive."""
    import motmetrics as mm

    from core.localization import TrackerConfig

    hold = TrackerConfig().coast_after if hold_s is None else hold_s
    acc = mm.MOTAccumulator(auto_id=True)
    series = {tid: pts for tid, pts in run.points.items()}
    for f in range(first, frames + 1):
        tau = run.t0 + (f - 1) / SOURCE_FPS
        hyp_ids, hyp_xy = [], []
        for tid, pts in series.items():
            # The target's latest position at the frame's time, unless it is coasting: what
            # GET /targets shows then (a frame that missed the target, or that the node skipped,
            # leaves its previous position).
            j = int(np.searchsorted(pts[:, 0], tau + EPS_S, side="right")) - 1
            if j >= 0 and tau - pts[j, 0] <= hold + EPS_S:
                hyp_ids.append(tid)
                hyp_xy.append(pts[j, 1:3])
        hyp = np.asarray(hyp_xy, dtype=np.float64).reshape(-1, 2)
        rows = truth.rows(f)
        counted = rows & (truth.conf == 1)
        ignored = truth.world[rows & (truth.conf == 0)]
        gt = truth.world[counted]
        keep = np.ones(len(hyp), dtype=bool)
        if len(ignored) and len(hyp):
            every = np.vstack([gt, ignored])
            d = np.linalg.norm(every[:, None] - hyp[None], axis=2)
            cost = np.where(d <= MATCH_M, d, 1e6)
            r, c = linear_sum_assignment(cost)
            on_ignored = c[(r >= len(gt)) & (cost[r, c] < 1e6)]
            keep[on_ignored] = False
        ids = [h for h, k in zip(hyp_ids, keep, strict=True) if k]
        dist = mm.distances.norm2squared_matrix(gt, hyp[keep], max_d2=MATCH_M**2)
        acc.update(truth.ident[counted].tolist(), ids, dist)
    mh = mm.metrics.create()
    names = ["mota", "idf1", "num_switches", "num_false_positives", "num_misses", "num_matches"]
    row = mh.compute(acc, metrics=names, name="run").loc["run"]
    return TrackScore(
        mota=float(row["mota"]),
        idf1=float(row["idf1"]),
        switches=int(row["num_switches"]),
        false_positives=int(row["num_false_positives"]),
        misses=int(row["num_misses"]),
        matches=int(row["num_matches"]),
        frames=frames,
    )


def run_tracking(
    frames: int, workdir: Path, every_frame: bool = False, flip: bool = False
) -> tuple[TrackScore, TrackingRun, Placement]:
    """Place the camera, play the first `frames` frames of the clip through serve + node (or,
    `every_frame`, post every frame's boxes detected beforehand; `flip`, the detector's tiles
    and their mirror images) and score the tracks on ground-truth frames 1..frames."""
    truth = load_truth()
    placement = place_camera(truth)
    clip = clip_video(video_path(), frames, workdir / "clip.mkv")
    posted = None
    if every_frame:
        from core.localization.appearance import box_appearance
        from core.localization.ssd_people import SsdConfig, SsdPeopleDetector

        config = SsdConfig(flip=flip)
        dnn = SsdPeopleDetector(config=config)
        posted = []
        for image in read_frames(clip, frames):
            found = dnn.detect_boxes(image)
            posted.append((found, box_appearance(image, found.boxes)))
    node_args = ("--flip",) if flip else ()
    run = track_through_service(clip, placement, workdir, posted, node_args)
    return score_tracking(run, truth, frames), run, placement


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=400, help="ground-truth frames (<= 400)")
    parser.add_argument("--skip-detectors", action="store_true")
    parser.add_argument("--skip-tracking", action="store_true")
    parser.add_argument("--workdir", type=Path, help="keep the logs and the service's data here")
    parser.add_argument(
        "--every-frame",
        action="store_true",
        help="post every frame's boxes (detected beforehand) at 7 Hz instead of running the node",
    )
    parser.add_argument(
        "--flip",
        action="store_true",
        help="track with the detector's tiles and their mirror images (the node's --flip)",
    )
    args = parser.parse_args()
    frames = min(max(args.frames, 1), 400)
    video = video_path()
    if not video.is_file():
        raise SystemExit(f"no clip at {video}: set {VIDEO_ENV} (see bench/bench_pets.py)")
    truth = load_truth()
    placement = place_camera(truth)
    err = placement.errors
    print(
        f"camera placed from {len(err)} floor points: f = {placement.K[0, 0]:.1f} px, height "
        f"{placement.T_world_camera[2, 3]:.2f} m, reprojection median {np.median(err):.2f} px, "
        f"95th percentile {np.percentile(err, 95):.2f} px"
    )
    if not args.skip_detectors:
        print(f"\npeople detectors on frames 1-{frames} (boxes at IoU {IOU}; fps per core)")
        for r in measure_detectors(read_frames(video, frames), truth):
            s = r.score
            speeds = "  ".join(f"{w}x{h}: {fps:6.1f} fps" for (w, h), fps in r.fps_by_size.items())
            print(
                f"  {r.name:34s} precision {s.precision:.3f} recall {s.recall:.3f} "
                f"(hits {s.hits}, false {s.false_positives}, missed {s.misses})  {speeds}"
            )
        print(f"  goal: dnn >= {GOAL_FPS:g} fps per 768x576 camera on one core")
    if not args.skip_tracking:
        if args.workdir is not None:
            args.workdir.mkdir(parents=True, exist_ok=True)
            score, run, _ = run_tracking(frames, args.workdir, args.every_frame, args.flip)
        else:
            with tempfile.TemporaryDirectory(prefix="bench-pets-") as tmp:
                score, run, _ = run_tracking(frames, Path(tmp), args.every_frame, args.flip)
        posted = re.search(r"posted (\d+) detection\(s\) and (\d+) empty frame", run.node_log)
        how = "every frame's boxes posted at 7 Hz" if args.every_frame else "intspace node"
        print(f"\nintspace serve + {how} on frames 1-{frames} (floor, 1 m)")
        detected = re.search(r"(\d+) detected in", run.node_log)
        if detected:
            print(f"  node: detected in {detected.group(1)} of {frames} frames")
        if posted:
            print(f"  node: {posted.group(1)} detections, {posted.group(2)} empty frames posted")
        print(
            f"  MOTA {score.mota:.3f} (goal >= {GOAL_MOTA})  IDF1 {score.idf1:.3f} (goal >= "
            f"{GOAL_IDF1})  switches {score.switches}  false positives {score.false_positives}  "
            f"misses {score.misses}  matches {score.matches}"
        )
        print(f"  person targets {len(run.points)}  robot targets {run.robot_targets} (goal 0)")
        truth = load_truth()
        halves = [(1, frames // 2), (frames // 2 + 1, frames)] if frames >= 2 else []
        for first, last in halves:
            part = score_tracking(run, truth, last, first=first)
            print(
                f"  frames {first}-{last}: MOTA {part.mota:.3f}  IDF1 {part.idf1:.3f}  switches "
                f"{part.switches}  false positives {part.false_positives}  misses {part.misses}"
            )


if __name__ == "__main__":
    main()
