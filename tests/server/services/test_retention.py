"""What piles up is pruned by age: detections after their retention, track points and ended
targets after theirs; live targets and recent rows stay."""

from __future__ import annotations

import time

import numpy as np
from sqlalchemy import func, select

from core.localization import NetworkCamera
from server.db.models import Detection, Target, TrackPoint

K = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]


def test_retention_deletes_old_rows_only(client, admin):
    cam = NetworkCamera.looking_at(K, None, [0.0, 0.0, 2.8], [2.0, 1.5, 0.0], (640, 480))
    body = {
        "name": "c0",
        "width": 640,
        "height": 480,
        "K": K,
        "dist": [0.0] * 5,
        "T_world_camera": cam.T_world_camera.tolist(),
    }
    cid = client.post("/api/v1/cameras", json=body, headers=admin).json()["id"]
    now = time.time()
    px = cam.project(np.array([[2.0, 1.5, 0.0]]))[0].tolist()
    obs = [{"camera_id": cid, "t": now, "pixel": px, "target": "cup"}]
    assert (
        client.post("/api/v1/observations", json={"observations": obs}, headers=admin).json()[
            "stored"
        ]
        == 1
    )
    live = client.app.state.runtime.targets
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and live.get("cup") is None:
        time.sleep(0.05)
    live.flush()
    factory = client.app.state.runtime.session_factory

    def counts():
        with factory() as s:
            return tuple(
                s.scalar(select(func.count()).select_from(m))
                for m in (Detection, TrackPoint, Target)
            )

    assert counts() == (1, 1, 1)
    # An hour and a bit later the detection goes (1 h), the track point and target stay (1 day).
    gone = live.apply_retention(now + live.detection_retention_s + 1)
    assert gone == {"detections": 1, "track_points": 0, "targets": 0}
    assert counts() == (0, 1, 1)
    # A day later the track point goes; the target goes once it has ended.
    later = now + live.track_retention_s + 1
    with factory() as s:
        s.execute(Target.__table__.update().values(state="confirmed"))
        s.commit()
    assert live.apply_retention(later)["targets"] == 0  # still live: kept
    with factory() as s:
        s.execute(Target.__table__.update().values(state="ended"))
        s.commit()
    assert live.apply_retention(later)["targets"] == 1
    assert counts() == (0, 0, 0)
