"""A replay of Frigate's `frigate/events` for walkers seen by ceiling cameras, with Frigate's
real message pattern (docs.frigate.video, "MQTT": frigate/events; the rules are those of
Frigate's current frigate/camera/state.py and frigate/track/tracked_object.py): `new` once
Frigate's tracker has kept an object for a few detect frames; then an `update` when

* the object's path grows: its bottom centre (normalised by the detect size) has moved
  0.05 * diagonal / longer side from the path's last point (and once on the frame after `new`),
* its state changes between active and stationary (more than `detect.stationary.threshold`
  frames within its box), or its position changes (it moves off the box it stood in),
* a better snapshot was taken (a higher score, or as good a score with a larger box) and the
  last update is more than 5 s old,
* or a minute has passed;

nothing while a person stands still, `end` when the object has been gone for a second (objects
still seen when the replay stops are kept). Boxes are [x0, y0, x1, y1] in the detect
resolution, the body's projected bounding box with a detector's jitter. The truth (positions)
is for scoring only."""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from core.localization import NetworkCamera

DETECT_FPS = 5.0
CONFIRM_FRAMES = 3  # frames before Frigate publishes `new`
GONE_FRAMES = 5  # frames unseen before `end`
# Frames within its box before Frigate calls an object stationary: detect.stationary.threshold,
# set to 10 (2 s at 5 fps) as docs/home-automation.md advises (Frigate's default is 50).
STATIONARY_FRAMES = 10
# Frigate's path step: the fraction of the detect frame's diagonal over its longer side.
PATH_STEP = 0.05
# A better snapshot is published at most this often (s) unless something else changed.
SNAPSHOT_PERIOD_S = 5.0
BODY_RADIUS, BODY_HEIGHT = 0.25, 1.7


def body_boxes(cam: NetworkCamera, xy: np.ndarray, scale: float) -> np.ndarray:
    """Return the boxes (..., 4) in detect pixels (camera pixels * scale) of people standing at
    xy (..., 2); NaN rows where the feet are out of the image or xy is NaN."""
    xy = np.asarray(xy, dtype=np.float64)
    flat = xy.reshape(-1, 2)
    out = np.full((flat.shape[0], 4), np.nan)
    feet = np.c_[flat, np.zeros(len(flat))]
    valid = ~np.isnan(flat).any(axis=1)
    valid[valid] = cam.in_view(feet[valid])
    if valid.any():
        ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        rim = BODY_RADIUS * np.c_[np.cos(ang), np.sin(ang)]
        n = int(valid.sum())
        pts = np.empty((n, 24, 3))
        pts[:, :, :2] = flat[valid][:, None, :] + np.vstack([rim, rim])[None]
        pts[:, :12, 2], pts[:, 12:, 2] = 0.0, BODY_HEIGHT
        px = cam.project(pts.reshape(-1, 3)).reshape(n, 24, 2)
        w, h = cam.image_size
        box = np.concatenate([px.min(axis=1), px.max(axis=1)], axis=1)
        out[valid] = np.clip(box, 0, [w - 1, h - 1, w - 1, h - 1]) * scale
    return out.reshape(*xy.shape[:-1], 4)


def body_box(cam: NetworkCamera, xy: np.ndarray, scale: float) -> np.ndarray | None:
    """Return a person's box in detect pixels (camera pixels * scale), None when the feet are
    out of the image."""
    box = body_boxes(cam, np.asarray(xy, dtype=np.float64)[None], scale)[0]
    return None if np.isnan(box).any() else box


def iou(a: np.ndarray, b: np.ndarray) -> float:
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[2], b[2]), min(a[3], b[3])
    inter = max(0.0, x1 - x0) * max(0.0, y1 - y0)
    area = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / area if area > 0 else 0.0


@dataclass
class _Object:
    id: str
    start: float
    seen: int = 0
    unseen: int = 0
    published: bool = False
    best_score: float = 0.0
    best_area: float = 0.0
    reference: np.ndarray | None = None
    still: int = 0
    stationary: bool = False
    position_changes: int = 0
    last_sent: float = 0.0
    last_thumb: float = 0.0
    path: list = field(default_factory=list)
    last: dict = field(default_factory=dict)


def frigate_messages(
    cams: dict[str, NetworkCamera],
    scale: float,
    positions,  # callable t -> (W, 2), NaN rows for walkers not present
    duration: float,
    t0: float,
    rng: np.random.Generator,
    jitter_px: float = 1.0,
    frames: list[tuple[float, str, list[np.ndarray]]] | None = None,
    paths: bool = True,
) -> list[tuple[float, str]]:
    """Return Frigate's messages (frame_time, JSON payload) in time order; `frames`, when
    given, receives every detect frame as (frame_time, camera, the boxes detected), the boxes
    a steady stream of detections would carry. paths: False for an older Frigate (no
    `path_data`, no update when the path grows)."""
    out: list[tuple[float, str]] = []
    for name, cam in cams.items():
        objects: dict[int, _Object] = {}
        phase = rng.uniform(0, 1 / DETECT_FPS)
        times = np.arange(phase, duration, 1 / DETECT_FPS)
        every = body_boxes(cam, np.stack([positions(float(t)) for t in times]), scale)
        for t, boxes in zip(times, every, strict=True):
            frame_time = t0 + float(t)
            seen: list[np.ndarray] = []
            if frames is not None:
                frames.append((frame_time, name, seen))
            for w in range(boxes.shape[0]):
                box = None if np.isnan(boxes[w]).any() else boxes[w]
                obj = objects.get(w)
                if box is None:
                    if obj is not None:
                        obj.unseen += 1
                        if obj.unseen >= GONE_FRAMES:
                            if obj.published:
                                after = {**obj.last, "end_time": frame_time}
                                out.append((frame_time, _event("end", obj.last, after)))
                            del objects[w]
                    continue
                box = box + rng.normal(0, jitter_px, 4)
                seen.append(box)
                if obj is None:
                    fid = f"{frame_time:.6f}-{rng.integers(1e6):06d}"
                    obj = objects[w] = _Object(fid, frame_time)
                obj.unseen = 0
                obj.seen += 1
                score = float(np.clip(0.8 + rng.normal(0, 0.05), 0.5, 0.99))
                area = float((box[2] - box[0]) * (box[3] - box[1]))
                was_stationary = obj.stationary
                if obj.reference is None or iou(box, obj.reference) < 0.6:
                    # Off the box it stood in: Frigate counts the first move, then each move
                    # of an object that was stationary.
                    if obj.reference is not None and (obj.position_changes == 0 or was_stationary):
                        obj.position_changes += 1
                        changed_position = True
                    else:
                        changed_position = False
                    obj.reference, obj.still = box, 0
                else:
                    obj.still += 1
                    changed_position = False
                obj.stationary = obj.still > STATIONARY_FRAMES
                # Frigate's better thumbnail: a higher score, or as good with a larger box.
                better = score > obj.best_score or (
                    score >= obj.best_score - 0.02 and area > obj.best_area * 1.1
                )
                if better:
                    obj.best_score, obj.best_area = max(score, obj.best_score), area
                    obj.last_thumb = frame_time
                path_update = False
                if paths and obj.seen >= CONFIRM_FRAMES:  # no longer a false positive
                    w, h = scale * np.asarray(cam.image_size, dtype=np.float64)
                    foot = (round(0.5 * (box[0] + box[2]) / w, 4), round(box[3] / h, 4))
                    step = PATH_STEP * np.hypot(w, h) / max(w, h)
                    if (
                        not obj.path
                        or len(obj.path) == 1
                        or np.hypot(*np.subtract(foot, obj.path[-1][0])) >= step
                    ):
                        obj.path.append((foot, frame_time))
                        path_update = True
                after = {
                    "id": obj.id,
                    "camera": name,
                    "frame_time": frame_time,
                    "label": "person",
                    "sub_label": None,
                    "top_score": max(score, obj.last.get("top_score", 0.0)),
                    "false_positive": False,
                    "start_time": obj.start,
                    "end_time": None,
                    "score": score,
                    "box": [round(float(v)) for v in box],
                    "area": int(area),
                    "ratio": float((box[2] - box[0]) / max(box[3] - box[1], 1)),
                    "region": [0, 0, 320, 320],
                    "active": not obj.stationary,
                    "stationary": obj.stationary,
                    "motionless_count": obj.still,
                    "position_changes": obj.position_changes,
                    "current_zones": [],
                    "entered_zones": [],
                    "has_clip": False,
                    "has_snapshot": True,
                }
                if paths:
                    after["path_data"] = [[list(p), pt] for p, pt in obj.path]
                kind = None
                if not obj.published and obj.seen >= CONFIRM_FRAMES:
                    kind, obj.published = "new", True
                elif obj.published and (
                    path_update
                    or changed_position
                    or obj.stationary != was_stationary
                    or frame_time - obj.last_sent > 60
                    or (
                        frame_time - obj.last_sent > SNAPSHOT_PERIOD_S
                        and obj.last_thumb > obj.last_sent
                    )
                ):
                    kind = "update"
                if kind is not None:
                    out.append((frame_time, _event(kind, obj.last or after, after)))
                    obj.last_sent = frame_time
                obj.last = after
    out.sort(key=lambda m: m[0])
    return out


def _event(kind: str, before: dict, after: dict) -> str:
    return json.dumps({"type": kind, "before": before, "after": after})


class Publisher(threading.Thread):
    """Publishes (frame_time, payload) on frigate/events when the wall clock reaches
    frame_time + delay (Frigate's processing and MQTT delay)."""

    def __init__(self, client, messages: list[tuple[float, str]], delay: float = 0.1) -> None:
        super().__init__(daemon=True)
        self.client = client
        self.messages = messages
        self.delay = delay
        self.sent = 0

    def run(self) -> None:
        for frame_time, payload in self.messages:
            wait = frame_time + self.delay - time.time()
            if wait > 0:
                time.sleep(wait)
            self.client.publish("frigate/events", payload, qos=1)
            self.sent += 1
