"""The tracker of one space: a core Tracker (here, or in the trackers' process), its reorder
buffer, its cameras' state and the stored detections it was fed."""

from __future__ import annotations

import threading
from collections import OrderedDict

from core.localization import Occluders
from core.localization.reorder import ReorderBuffer
from core.localization.tracking import Tracker, TrackerConfig, TrackState
from server.services.tracking.process import RemoteTracker, TrackerHost

# Detection ids a tracker remembers having been fed (one frame may reach it twice around a
# takeover: from the replay and from its notification).
_FED_IDS = 200_000


class SpaceTracker:
    """The tracker of one space (here, or in the trackers' process `host`), its reorder buffer
    and its cameras."""

    def __init__(
        self,
        space_id: int | None,
        config: TrackerConfig,
        latency: float,
        next_id: int,
        occluders: Occluders | None,
        host: TrackerHost | None = None,
    ):
        self.space_id = space_id
        self.tracker: Tracker | RemoteTracker
        if host is None:
            self.tracker = Tracker(config=config, next_id=next_id, occluders=occluders)
        else:
            self.tracker = RemoteTracker(host, config, next_id, occluders)
        self.buffer = ReorderBuffer(latency=latency)
        self.cameras_loaded = -float("inf")
        self.refused: dict[int, str] = {}
        self.states: dict[int, TrackState] = {}
        # Held while the tracker thread changes the tracker, so readers see a whole state.
        self.lock = threading.RLock()
        # Service time at which the space's world was held still (the twin paused), or None.
        self.held_since: float | None = None
        self.fed: OrderedDict[int, None] = OrderedDict()

    def close(self) -> None:
        """Let the tracker go (the space was reset or given up)."""
        if isinstance(self.tracker, RemoteTracker):
            self.tracker.close()

    def fresh(self, ids: tuple[int, ...]) -> bool:
        """Whether a frame of stored detections `ids` is new to this tracker (and remember it);
        a frame without ids (not stored by id) always is."""
        if not ids:
            return True
        if ids[0] in self.fed:
            return False
        for i in ids:
            self.fed[i] = None
        while len(self.fed) > _FED_IDS:
            self.fed.popitem(last=False)
        return True
