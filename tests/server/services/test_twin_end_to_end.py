"""The twin as cameras, end to end (spec 08, issue section 4): `intspace serve` with the default
home -> MJPEG streams -> one `intspace node` -> POST /observations -> the space's tracker ->
/ws/targets, against the in-process path (the same service detecting in its own frames).

The machinery (and the longer run) is bench/bench_end_to_end.py: both services run side by
side as a user starts them (subprocesses, SQLite, the admin token from the environment, the
twin at its default 5 Hz), are scored from outside through the public API against the twin's
robot pose at each track point's own capture time, over the same 8 s of simulated time.
"""

from __future__ import annotations

import time

import numpy as np

from bench.bench_end_to_end import compare, describe, paired
from server.node.sources import MjpegHttpSource
from tests.support.mjpeg_stream import MjpegStream, flat_jpeg
from tests.support.waiting import wait_until

# Simulated seconds scored: 40 twin steps, enough for an RMSE whose paired ratio is stable
# (both paths see the same stretch of the patrol, so the calibration's error is common to both),
# short enough for CI.
SECONDS = 8.0
# The tracker's reorder window (INTSPACE_TRACKER_LATENCY_S, its default) in both services. A
# frame is stamped with its capture time and reaches the tracker after the twin rendered the
# cameras before it, the stream, the node's decoding and detection, and the POST: 0.1-0.3 s on
# a quiet machine, more under CI's load. The tracker releases frames once every camera it hears
# from has delivered frames as recent, and refuses a frame older than the window as late; with
# a 0.15 s window it refused most of the node's frames on a loaded machine (bench/
# bench_end_to_end.py measures it). Both paths get the same window, so the comparison is fair.
TRACKER_LATENCY_S = 1.0


def test_node_path_tracks_the_robot_as_well_as_the_in_process_path(tmp_path):
    external, internal = compare(tmp_path, seconds=SECONDS, tracker_latency_s=TRACKER_LATENCY_S)
    both = paired(external, internal)
    report = (
        f"{describe(external)}\n{describe(internal)}\n"
        f"paired over {both.steps} steps: node {100 * both.external_rmse_m:.2f} cm, in-process "
        f"{100 * both.internal_rmse_m:.2f} cm, ratio {both.ratio:.2f}"
    )
    print(report)
    # Ten steps in common at least: an RMSE of fewer points says little. Frames the tracker
    # refuses as late (delivered after its reorder window) are what costs the node's path
    # steps; the report gives their count.
    assert both.steps >= 10, report
    # The anchor: the in-process path meets spec 08's 5 cm for points at a known height (the
    # robot's marker), measured against the twin's true pose (0.5 cm measured here since the
    # network is registered to the world by the signposts; 2-3.5 cm before, mostly the frame's
    # error, common to both paths).
    assert both.internal_rmse_m <= 0.05, report
    # Spec 08 asks the node's path (the twin's JPEG at quality 90 with 4:4:4 chroma, the
    # stream, the node's clock) for 1.2x. bench/bench_end_to_end.py measures 1.06x over 60 s
    # (0.67 cm against 0.63 cm); over the 40 steps here the ratio of two sub-centimetre RMSEs
    # spreads (0.99-1.14 measured; 1.08-1.36 with 4:2:0 chroma at quality 85, which moved the
    # marker's detected centre by 0.12 px RMS), so this allows 1.2x plus 2 mm: the node's path
    # cannot lose more than its images lose without the test failing.
    assert both.external_rmse_m <= 1.2 * both.internal_rmse_m + 0.002, report
    # Every scored point reached the WebSocket, within the reorder window plus a second: the
    # rest is the stream, the node's decoding and detection, the POST, the tracker and the
    # WebSocket (at most 30 messages a second), up to 0.55 s measured at a load of 13 on two
    # cores; a node that queued frames instead of keeping the newest would drift further
    # behind with every frame. Spec 08's 200 ms p95 needs a window far below this one: the
    # bench reports it, this test does not assert it.
    latency = external.latency
    assert latency.size and np.all(np.isfinite(latency)), report
    assert external.latency_percentile(95) < TRACKER_LATENCY_S + 1.0, report
    # The node read every camera of the home and reported it (online, or stalled when a loaded
    # machine holds the twin's renders back for 2 s: never offline while the node runs).
    assert external.cameras, report
    for name, health in external.cameras.items():
        assert health["status"] != "offline" and health["last_frame_t"] is not None, (name, report)


def test_a_stream_stopped_for_10_s_is_read_again_within_5_s_of_its_return():
    # While paused the camera holds every connection open and sends nothing, as the twin's
    # stream does while the twin is paused and as a camera does whose sensor hung: only the
    # reader's read timeout notices.
    camera = MjpegStream([flat_jpeg()], fps=20.0)
    source = MjpegHttpSource("pausing", camera.url)
    try:
        source.start()
        wait_until(
            lambda: source.stats.frames >= 5,
            what="5 frames from the stream",
            stalled_after_s=5,
            poll_s=0.05,
        )
        camera.paused.set()
        time.sleep(10.0)  # the outage itself: time must pass with the stream stopped
        # Stalled all along: the read timeout (2 s) cut each held connection, and the reader
        # kept trying with its back-off.
        assert source.stats.stalls >= 3 and source.stats.reconnects >= 3
        stalled_frames = source.stats.frames
        camera.paused.clear()
        back = time.time()
        while source.stats.frames == stalled_frames and time.time() < back + 8:
            time.sleep(0.01)
        assert source.stats.last_received is not None
        delay = source.stats.last_received - back
        print(f"read again {delay:.2f} s after the stream returned")
        # Spec 08: within 5 s. The reader is either holding a connection (frames at once) or
        # waiting out its back-off (1 s at most) before it reconnects.
        assert source.stats.frames > stalled_frames and delay <= 5.0, delay
    finally:
        source.stop()
        source.join(5)
        camera.close()
