"""The spaces' trackers: detections in, live targets out (spec 08's pipeline, service side).

`TrackingService.ingest` stores a batch of detections (the detections table, committed before it
returns) and queues them, one camera frame (camera, capture time) at a time, for the tracker of
the cameras' space, with the frames in which the senders detected nothing (not stored). A
background thread releases the queued frames in time order, feeds them to
core.localization.tracking.Tracker, and hands its reports to the live targets store. The
association and filtering are all in core; this package only moves frames and results.

Several processes on one PostgreSQL database (`shared_database_url`) share the spaces' trackers:
each space's runs in the one process that holds the space's lock, the others send it their
camera frames and show its target changes, and a process that gets a free lock takes the space
over (`sharing`). On a shared database the core trackers themselves run in a child process
(`process`), so that their arithmetic does not hold the service's interpreter lock.

The modules, from the bottom up:

* `ingest`: detections to ingest, camera frames, what ingest did, the frames' stage delays.
* `wire`: the channels between processes and a camera frame as a notification item.
* `process`: the trackers' child process and the tracker that calls it.
* `space`: the tracker of one space, its reorder buffer and cameras.
* `snapshots`: live targets as the tracker's snapshots, to restore tracks.
* `trackers`: the spaces' trackers of this process, fed and published.
* `sharing`: frames routed to the process that tracks their space; ownership and takeover.
* `service`: `TrackingService`, ingest, hold / release / reset and the tracker thread.

Times are Unix seconds on the service's clock.
"""

from server.services.tracking.ingest import (
    CameraFrame,
    DetectionIn,
    FrameDelays,
    IngestResult,
    camera_frames,
    empty_frame,
)
from server.services.tracking.process import TrackerProcessError
from server.services.tracking.service import TrackingService
from server.services.tracking.wire import CONTROL_CHANNEL, DETECTIONS_CHANNEL, TARGETS_CHANNEL

__all__ = [
    "CONTROL_CHANNEL",
    "DETECTIONS_CHANNEL",
    "TARGETS_CHANNEL",
    "CameraFrame",
    "DetectionIn",
    "FrameDelays",
    "IngestResult",
    "TrackerProcessError",
    "TrackingService",
    "camera_frames",
    "empty_frame",
]
