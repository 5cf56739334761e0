"""The camera node's people detector per camera (spec 08, "Real footage"): which detector a
camera runs, its settings from YAML and flags, a file's frames timed by --source-fps, and
PETS 2009 through `intspace serve` and `intspace node`, scored on the floor."""

from __future__ import annotations

import os
import time

import cv2
import numpy as np
import pytest

from bench import bench_pets
from core.errors import InvalidInput
from core.localization.detect import PersonDetector
from core.localization.ssd_people import SsdConfig, SsdPeopleDetector
from server.cli import main
from server.commands.node import _config, register
from server.node.config import CameraConfig, load_config
from server.node.runner import detector_kind, people_detector
from server.node.sources import OpenCvSource

API = "http://127.0.0.1:8000/api/v1"


def test_real_sources_get_the_neural_detector_and_the_twin_streams_the_background_one():
    def kind(source, **kw) -> str:
        return detector_kind(CameraConfig(name="c", source=source, **kw), API)

    # The service streams only the twin's cameras: their people are coloured cylinders.
    assert kind(f"{API}/cameras/3/stream.mjpg") == "background"
    assert kind("http://127.0.0.1:8000/api/v1/cameras/3/stream.mjpg") == "background"
    for real in ("rtsp://192.168.1.20/stream1", 0, "/data/entrance.avi", "http://cam.local/v"):
        assert kind(real) == "dnn"
    assert kind("/data/entrance.avi", detector="background") == "background"
    assert kind(f"{API}/cameras/3/stream.mjpg", detector="dnn") == "dnn"
    camera = CameraConfig(name="c", source=0, score_threshold=0.7, min_person_px=40)
    dnn = people_detector(camera, "dnn", None)
    assert isinstance(dnn, SsdPeopleDetector)
    assert dnn.config.score_threshold == 0.7 and dnn.config.min_person_px == 40
    assert not dnn.config.flip  # twice the cost: asked for, never by default
    flipped = people_detector(camera.model_copy(update={"flip": True}), "dnn", None)
    assert isinstance(flipped, SsdPeopleDetector) and flipped.config.flip
    assert flipped.config.score_threshold == 0.7  # the user's threshold wins
    # Unset, the threshold is the model zoo's own, with or without the mirror views (none is
    # fitted to footage).
    plain = CameraConfig(name="c", source=0)
    for flip in (False, True):
        made = people_detector(plain.model_copy(update={"flip": flip}), "dnn", None)
        assert isinstance(made, SsdPeopleDetector) and made.config.score_threshold == 0.5
    # The tiles: 230 px (each enlarged 1.3 times to the model's input) unless asked.
    assert plain.tile_px == SsdConfig().tile_px == 230
    large = people_detector(plain.model_copy(update={"tile_px": 300}), "dnn", None)
    assert isinstance(large, SsdPeopleDetector) and large.config.tile_px == 300
    assert isinstance(people_detector(camera, "background", None), PersonDetector)


def test_detector_settings_from_yaml_and_flags_are_validated():
    config = load_config(
        "cameras:\n"
        "  - name: gate\n    source: /v.avi\n    detector: dnn\n    score_threshold: 0.6\n"
        "    min_person_px: 32\n    source_fps: 7\n"
        "    masks: [[[0, 0], [10, 0], [10, 10]]]\n"
    )
    cam = config.cameras[0]
    assert (cam.detector, cam.score_threshold, cam.min_person_px, cam.source_fps) == (
        "dnn",
        0.6,
        32,
        7,
    )
    for bad, field in [
        ("detector: hog", "detector"),
        ("score_threshold: 1.2", "score_threshold"),
        ("source_fps: 0", "source_fps"),
        ("tile_px: 150", "tile_px"),  # smaller than twice the tiles' row overlap
    ]:
        with pytest.raises(InvalidInput, match=field):
            load_config(f"cameras:\n  - name: gate\n    source: /v.avi\n    {bad}\n")

    import argparse

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())

    def parse(*argv: str):
        return _config(parser.parse_args(["node", *argv]))

    config = parse(
        "--source",
        "/v.avi",
        "--camera",
        "gate",
        "--detector",
        "background",
        "--score-threshold",
        "0.3",
        "--min-person-px",
        "12",
        "--source-fps",
        "7",
        "--tile-px",
        "300",
        "--mask",
        "0,0 10,0 10,10",
        "--mask",
        "20,20 30,20 30,30 20,30",
    )
    cam = config.cameras[0]
    assert (cam.detector, cam.score_threshold, cam.min_person_px, cam.source_fps) == (
        "background",
        0.3,
        12,
        7,
    )
    assert cam.masks == [[[0, 0], [10, 0], [10, 10]], [[20, 20], [30, 20], [30, 30], [20, 30]]]
    assert cam.tile_px == 300
    with pytest.raises(InvalidInput, match="--tile-px"):
        parse("--source", "/v.avi", "--camera", "gate", "--tile-px", "64")
    with pytest.raises(InvalidInput, match="--score-threshold"):
        parse("--source", "/v.avi", "--camera", "gate", "--score-threshold", "2")
    with pytest.raises(InvalidInput, match="--mask"):
        parse("--source", "/v.avi", "--camera", "gate", "--mask", "0,0 1,1")
    with pytest.raises(InvalidInput, match="not both"):
        parse("--config", "nodes.yaml", "--detector", "dnn")


def test_bad_flags_are_one_line_and_exit_code_2(monkeypatch, capsys):
    monkeypatch.setenv("INTSPACE_TOKEN", "t")
    assert main(["node", "--camera", "c", "--source", "x.avi", "--source-fps", "-1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--source-fps" in err


def test_a_file_with_a_source_fps_is_timed_from_its_start(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for k in range(6):
        writer.write(np.full((48, 64, 3), 30 * k, np.uint8))
    writer.release()
    # The container says 10 fps; the footage was taken at 25: frame k at t0 + k / 25, played
    # at 25 frames per second.
    source = OpenCvSource("clip", str(path), realtime=True, source_fps=25.0)
    started = time.time()
    source.start()
    taken = []
    while (frame := source.frames.take(timeout=5)) is not None:
        taken.append(frame)
    source.join(5)
    assert len(taken) + source.frames.dropped == 6
    t0 = taken[0].captured - (taken[0].seq - 1) / 25.0
    assert started - 0.01 <= t0 <= started + 2.0  # stamped from when the file was opened
    for frame in taken:
        assert frame.captured == pytest.approx(t0 + (frame.seq - 1) / 25.0, abs=1e-9)
        assert frame.t is None  # no stream stamp: the node adds its clock offset
    # Played at 25 fps, not the container's 10: 5 frame periods after the first.
    assert taken[-1].received - taken[0].received < 5 / 10.0
    with pytest.raises(InvalidInput):
        OpenCvSource("clip", str(path), source_fps=0.0)


# Frames 1-150 of the clip, 21 s at 7 fps: a third of the development half, same conditions.
# Over frames 1-400 the pipeline is measured by `python -m bench.bench_pets` (spec 08's goals
# there: MOTA >= 0.75, IDF1 >= 0.70; docs/real-cameras.md has the figures). A live node skips
# frames rather than fall behind when its core is shared (CI runs two test workers on two
# cores): with the 300 px tiles the node had before, the same tracker on frames 1-150 with
# frames skipped at random scored MOTA 0.62-0.63, IDF1 0.63-0.67 with a quarter skipped,
# 0.52-0.56 and 0.56-0.66 with 40 %, 0.36-0.48 and 0.50-0.58 with half (three seeds each); with
# the 230 px tiles this run scored MOTA 0.74 and IDF1 0.80-0.81 twice on a machine loaded to
# 6. The bounds hold up to about 40 % skipped; they are this shortened run's floor, far above
# the background model's (MOTA -0.06, IDF1 0.05), not spec 08's goal.
PETS_FRAMES = 150
PETS_MIN_MOTA = 0.45
PETS_MIN_IDF1 = 0.50


def test_pets_footage_through_serve_and_node_is_tracked_on_the_floor(tmp_path):
    video, truth = bench_pets.video_path(), bench_pets.truth_path()
    if not video.is_file() or not truth.is_file():
        message = f"the PETS 2009 clip ({video}) or its ground truth ({truth}) is missing"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(message + " (CI=true: .ci/run installs the clip)")
        pytest.skip(message)
    score, run, placement = bench_pets.run_tracking(PETS_FRAMES, tmp_path)
    print(score, f"robot targets {run.robot_targets}")
    # Placed from the ground truth's floor points: spec 08 asks a median <= 1 px.
    assert np.median(placement.errors) <= 1.0
    assert score.mota >= PETS_MIN_MOTA, (score, run.node_log)
    assert score.idf1 >= PETS_MIN_IDF1, (score, run.node_log)
    # No robot is registered in this space: spec 08 wants no robot target from it.
    assert run.robot_targets == 0, run.node_log
