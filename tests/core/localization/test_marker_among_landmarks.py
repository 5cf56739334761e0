"""The robot's marker and people among the home's landmarks, as the ceiling cameras see them.

The twin's ceiling frames show the landmarks (signposts' red rings, object marks' blue frames).
A signpost's rings are red like the robot's disc and, seen from the ceiling, often larger; the
marker detector must still find the disc, and nothing in a frame without robot and people may
be taken for either. Scored against the twin's truth.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from core.errors import InvalidInput
from core.localization import NetworkCamera, locate_monocular
from core.localization.detect import MarkerDetectorConfig, PersonDetector, detect_marker
from core.localization.detect.marker import _hue_mask
from core.localization.detections import detect_frame
from core.sim import Pose2D, Renderer, SensorNoise, WorldState, default_scene, world_state
from core.sim.render.landmarks import scene_landmarks
from core.sim.scenarios.multi_target_tracking import tracking_scene

NOISE = SensorNoise(sigma=2.0, blur_sigma=0.5)
# Kitchen floor seen by cam_kitchen_sw, which also faces signpost_25 on the bedroom wall: its
# rings span ~20 px there (208 px of red), more than the disc's 64-174 px at these poses.
KITCHEN = [(5.1, 1.0), (5.6, 1.5), (6.1, 1.0), (5.1, 2.0), (4.6, 1.5), (7.1, 1.0)]


@pytest.fixture(scope="module")
def home() -> Renderer:
    return Renderer(default_scene())


def _red_blobs(image: np.ndarray, cfg: MarkerDetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    mask = _hue_mask(cv2.cvtColor(image, cv2.COLOR_BGR2HSV), cfg)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    return labels, stats


def test_marker_found_beside_larger_signpost_rings(home: Renderer) -> None:
    scene = home.scene
    assert scene.robot is not None and scene.robot.marker is not None
    cfg = MarkerDetectorConfig(colour=scene.robot.marker.colour)
    cm = home.camera("cam_kitchen_sw")
    cam = NetworkCamera.from_pose(cm.K, cm.dist, cm.T_world_camera, (cm.width, cm.height))
    people = world_state(scene, 0.0).people
    px_err, floor_err = [], []
    for i, (x, y) in enumerate(KITCHEN):
        # The robot roughly faces the camera, its mast behind the disc (a mast that crosses
        # the disc is the detector's asymmetry test's case, not this one's).
        yaw = math.atan2(cm.position[1] - y, cm.position[0] - x) + 0.3 * (i - 2.5)
        frame = home.render(
            "cam_kitchen_sw", WorldState(0.0, Pose2D(x, y, yaw), people), rng=i, noise=NOISE
        )
        assert frame.marker_visible and frame.marker_ellipse_pixel is not None
        # The case under test: the largest red blob is a signpost's ring, not the disc.
        labels, stats = _red_blobs(frame.image, cfg)
        u, v = np.rint(frame.marker_ellipse_pixel).astype(int)
        largest = int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) + 1
        assert labels[v, u] != largest, f"the disc is the largest red blob at {(x, y)}"
        det = detect_marker(frame.image, cfg, background=home.empty("cam_kitchen_sw"))
        assert det is not None, f"marker missed at {(x, y)} beside signpost_25"
        px_err.append(np.linalg.norm(det.pixel - frame.marker_ellipse_pixel))
        # On the floor: the disc's centre at its height, through the true camera (scoring).
        xy = locate_monocular(cam, det.pixel[None], scene.robot.marker.height).xy[0]
        floor_err.append(np.linalg.norm(xy - [x, y]))
    # Measured 0.02-0.11 px: the soft-weight centroid's sub-pixel accuracy
    # (test_target_detection bounds it at 0.5 px), unchanged by the rings 100+ px away.
    assert max(px_err) < 0.5, px_err
    # 0.5 px at 2-4 m with f = 330 px is < 6 mm on the floor; measured below 2 mm.
    assert max(floor_err) < 0.01, floor_err


def test_a_half_hidden_signpost_is_not_the_marker() -> None:
    """The visitor stands where its walk pauses, in front of signpost_25 as cam_kitchen_sw sees
    it: what shows of the rings is a small convex red blob that passes every disc test (it was
    taken for the robot 13 times in one calibration drive). With the camera's view of the empty
    home as its background, the detector knows that red belongs to the room: no marker."""
    scene = tracking_scene()
    render = Renderer(scene)
    assert scene.robot is not None and scene.robot.marker is not None
    cfg = MarkerDetectorConfig(colour=scene.robot.marker.colour)
    visitor = tuple((1e4, 1e4) if p.name != "visitor" else (5.3, 2.5) for p in scene.people)
    image = render.render("cam_kitchen_sw", WorldState(0.0, None, visitor), rng=1).image
    # The case under test: without the background the fragment is taken for the disc.
    fragment = detect_marker(image, cfg)
    assert fragment is not None
    assert detect_marker(image, cfg, background=render.empty("cam_kitchen_sw")) is None
    # The same through the pipeline's entry point, with the background the person detector
    # learnt of the empty home.
    people = PersonDetector()
    people.learn(render.empty("cam_kitchen_sw"))
    found = detect_frame(image, marker=cfg, marker_height=0.36, people=people)
    assert [d.kind for d in found if d.kind == "robot"] == []


def test_a_background_of_another_size_is_refused() -> None:
    with pytest.raises(InvalidInput, match="background"):
        detect_marker(np.zeros((10, 10, 3), np.uint8), background=np.zeros((12, 10, 3), np.uint8))


def test_ring_is_not_taken_for_the_disc() -> None:
    """A red ring (a signpost's outer ring seen face on) larger than a red disc beside it: the
    ring's hole fails the fill test, so the disc is found, at its true centre."""
    img = np.full((200, 300, 3), 190, np.uint8)
    red = (30, 20, 220)  # BGR of the marker's (220, 20, 30)
    cv2.circle(img, (80, 100), 30, red, -1, cv2.LINE_AA)
    cv2.circle(img, (80, 100), 22, (255, 255, 255), -1, cv2.LINE_AA)
    cv2.circle(img, (220, 90), 8, red, -1, cv2.LINE_AA)
    det = detect_marker(img)
    assert det is not None
    # Drawn with cv2's anti-aliasing about (220, 90): its area centroid within 0.1 px.
    np.testing.assert_allclose(det.pixel, [220.0, 90.0], atol=0.1)
    # The ring alone is no marker (its fill, area / area inside its outline, is ~0.46).
    cv2.circle(img, (220, 90), 9, (190, 190, 190), -1)
    assert detect_marker(img) is None


def test_landmarks_alone_are_neither_robot_nor_people(home: Renderer) -> None:
    """Every ceiling camera, the home with its landmarks and neither robot nor people: no
    marker; a background model learnt on other frames of that home finds no person."""
    scene = home.scene.model_copy(update={"people": []})
    render = Renderer(scene)
    empty = WorldState(0.0, None, ())
    cfg = MarkerDetectorConfig(colour=(220, 20, 30))
    rings = 0
    for cam in scene.cameras:
        detector = PersonDetector(min_area=100)
        for i in range(5):
            detector.learn(render.render(cam.name, empty, rng=i, noise=NOISE).image)
        frame = render.render(cam.name, empty, rng=99, noise=NOISE)
        _, stats = _red_blobs(frame.image, cfg)
        rings += int(np.any(stats[1:, cv2.CC_STAT_AREA] >= 100))
        assert detect_marker(frame.image, cfg) is None, cam.name
        assert detector.detect(frame.image) == [], cam.name
    # The landmarks are there to be mistaken: 4 of the 5 cameras show a signpost's rings of
    # 117-207 red pixels (more than the robot's disc at most places).
    assert rings >= 4


def test_person_detector_finds_the_walker_not_the_landmarks(home: Renderer) -> None:
    """The walker crosses the kitchen past the signposts: every blob the background model
    reports is the walker (its bounding box holds the image of the walker's axis), none is a
    landmark."""
    scene = home.scene
    empty = scene.model_copy(update={"people": []})
    bg = Renderer(empty)
    name = "cam_kitchen_sw"
    cm = home.camera(name)
    det = PersonDetector(min_area=100)
    for i in range(5):
        det.learn(bg.render(name, world_state(empty, 0.0), rng=i, noise=NOISE).image)
    pages = [
        cm.project(lm.T_world_mark[:3, 3][None])[0]
        for lm in scene_landmarks(scene)
        if home.sees(name, lm.T_world_mark[:3, 3][None])[0]
    ]
    assert pages, "no landmark in view: the test would not test anything"
    seen = 0
    for t in np.arange(5.0, 12.0, 1.0):
        frame = home.render(name, world_state(scene, float(t)), rng=int(t), noise=NOISE)
        x, y = frame.people[0]  # truth: scoring only
        axis = cm.project(np.array([[x, y, 0.2], [x, y, 1.5]]))
        for p in det.detect(frame.image):
            bx, by, bw, bh = p.bbox
            inside = (axis[:, 0] >= bx - 2) & (axis[:, 0] <= bx + bw + 2)
            inside &= (axis[:, 1] >= by - 2) & (axis[:, 1] <= by + bh + 2)
            assert inside.any(), f"a blob at {p.bbox} at t = {t} is not the walker"
            seen += 1
    assert seen >= 3
