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
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bench.pets_clip import (  # noqa: E402
    VIDEO_ENV,
    Truth,
    load_truth,
    read_frames,
    truth_path,
    video_path,
)
from bench.pets_detectors import (  # noqa: E402
    IOU,
    BoxScore,
    DetectorResult,
    box_iou,
    measure_detectors,
    score_boxes,
)
from bench.pets_placement import Placement, place_camera  # noqa: E402
from bench.pets_tracking import (  # noqa: E402
    TrackingRun,
    TrackScore,
    run_tracking,
    score_tracking,
    track_through_service,
)

__all__ = [
    "BoxScore",
    "DetectorResult",
    "Placement",
    "TrackScore",
    "TrackingRun",
    "Truth",
    "box_iou",
    "load_truth",
    "measure_detectors",
    "place_camera",
    "read_frames",
    "run_tracking",
    "score_boxes",
    "score_tracking",
    "track_through_service",
    "truth_path",
    "video_path",
]

# spec 08's goals on the footage
GOAL_MOTA = 0.75
GOAL_IDF1 = 0.70
GOAL_FPS = 7.0


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
