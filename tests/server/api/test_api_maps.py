"""The coverage-and-accuracy map over the space's floor, as JSON and as a PNG floor plan; in
the digital twin's home it honours occlusion by the walls and furniture."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np

from core.localization import NetworkCamera, coverage_map
from core.sim import camera_model, default_scene, load_scene
from core.sim.occluders import scene_occluders

K = [[400.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]]


def test_coverage_json_and_png(client, admin):
    assert client.get("/api/v1/maps/coverage", headers=admin).status_code == 409
    space = client.post("/api/v1/spaces", json={"name": "flat"}, headers=admin).json()["id"]
    room = {"space_id": space, "name": "living", "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]]}
    assert client.post("/api/v1/rooms", json=room, headers=admin).status_code == 201
    assert client.get("/api/v1/maps/coverage", headers=admin).status_code == 409  # no camera
    cams = [
        NetworkCamera.looking_at(K, None, [0.2, 0.2, 2.8], [2.0, 1.5, 0.0], (640, 480)),
        NetworkCamera.looking_at(K, None, [3.8, 2.8, 2.8], [2.0, 1.5, 0.0], (640, 480)),
    ]
    for k, cam in enumerate(cams):
        body = {
            "name": f"c{k}",
            "space_id": space,
            "width": 640,
            "height": 480,
            "K": K,
            "T_world_camera": cam.T_world_camera.tolist(),
        }
        assert client.post("/api/v1/cameras", json=body, headers=admin).status_code == 201

    response = client.get("/api/v1/maps/coverage?spacing=0.25&height=0.5", headers=admin)
    assert response.status_code == 200, response.text
    body = response.json()
    expected = coverage_map(cams, (0, 4), (0, 3), spacing=0.25, height=0.5)
    assert np.allclose(body["x"], expected.x) and np.allclose(body["y"], expected.y)
    assert body["n_cameras"] == expected.n_cameras.tolist()
    std = np.array([[np.inf if v is None else v for v in row] for row in body["crb_std"]])
    assert np.allclose(std, expected.crb_std)

    png = client.get("/api/v1/maps/coverage?spacing=0.25&format=png&scale=4", headers=admin)
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    image = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_COLOR)
    # The map (16 x 12 cells of 4 px) at the top left, the 200 px legend panel on its right,
    # which is taller than this small map.
    assert image.shape[1] == 16 * 4 + 200 and image.shape[0] >= 12 * 4
    # A space that is not the twin's home has no floor plan: nothing is occluded.
    assert body["occlusion"] is None and body["fraction_hidden"] == 0.0
    assert body["occluders"] == []

    assert client.get("/api/v1/maps/coverage?spacing=0", headers=admin).status_code == 422
    assert client.get("/api/v1/maps/coverage?format=gif", headers=admin).status_code == 422


VIRIDIS_BRIGHT = (37, 231, 253)  # cv2.COLORMAP_VIRIDIS at 255 and 0, BGR
VIRIDIS_DARK = (84, 1, 68)


def _register(client, admin, scene) -> int:
    """Register the scene's home as the twin does at its first start: the space (named after
    the scene), its rooms and its cameras with their nominal calibration."""
    space = client.post("/api/v1/spaces", json={"name": scene.name}, headers=admin).json()["id"]
    for room in scene.rooms:
        body = {"space_id": space, "name": room.name, "polygon": [list(p) for p in room.polygon]}
        assert client.post("/api/v1/rooms", json=body, headers=admin).status_code == 201
    for spec in scene.cameras:
        m = camera_model(spec)
        body = {
            "name": spec.name,
            "space_id": space,
            "width": m.width,
            "height": m.height,
            "K": m.K.tolist(),
            "dist": m.dist.tolist(),
            "T_world_camera": m.T_world_camera.tolist(),
        }
        assert client.post("/api/v1/cameras", json=body, headers=admin).status_code == 201
    return space


def _cameras(scene) -> list[NetworkCamera]:
    models = [camera_model(spec) for spec in scene.cameras]
    return [
        NetworkCamera.from_pose(m.K, m.dist, m.T_world_camera, (m.width, m.height)) for m in models
    ]


def test_coverage_of_the_twin_home_honours_walls_and_draws_them(client, admin):
    # The registry keeps the twin's home after the simulation is switched off: same name and
    # rooms as the default scene, so the map takes its walls and furniture.
    scene = default_scene()
    space = _register(client, admin, scene)
    response = client.get(f"/api/v1/maps/coverage?space_id={space}", headers=admin)
    assert response.status_code == 200, response.text
    body = response.json()
    expected = coverage_map(
        _cameras(scene), (0.0, 8.0), (0.0, 6.0), spacing=0.1, occluders=scene_occluders(scene)
    )
    assert body["occlusion"] == "twin scene 'default_home'"
    assert body["n_cameras"] == expected.n_cameras.tolist()
    std = np.array([[np.inf if v is None else v for v in row] for row in body["crb_std"]])
    assert np.allclose(std, expected.crb_std, rtol=1e-9)
    # Over half of the camera-cell pairs in a camera's image are behind a wall or furniture
    # (56 % in the default home at 0.1 m).
    assert 0.5 < body["fraction_hidden"] < 0.65
    assert body["fraction_hidden"] == expected.fraction_hidden()
    assert len(body["occluders"]) == 22 and body["fraction_covered"]["1"] < 0.8
    # Every key of the map without occlusion is still there.
    assert {"x", "y", "height", "pixel_sigma", "n_cameras", "crb_std", "cameras"} <= body.keys()

    png = client.get(f"/api/v1/maps/coverage?space_id={space}&format=png&scale=5", headers=admin)
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    image = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (60 * 5, 80 * 5 + 200, 3)

    # 50 px per metre, +y up: pixel (row, col) is at x = (col + 0.5) / 50, y = 6 - (row + 0.5)
    # / 50. The wall x = 4.5 (10 cm thick: columns 222..227) is white where solid, at y = 0.5
    # and 2.5 and 5.0, and not at y = 1.45, in its door (y from 1.0 to 1.9).
    def px(x, y):
        return image[round((6.0 - y) * 50 - 0.5), round(x * 50 - 0.5)]

    for y in (0.5, 2.5, 5.0):
        assert tuple(px(4.5, y)) == (255, 255, 255), y
    assert tuple(px(4.5, 1.45)) != (255, 255, 255)
    # The kitchen/bedroom wall y = 3 is white at x = 5.0, and open in its door at x = 6.5.
    assert tuple(px(5.0, 3.0)) == (255, 255, 255)
    assert tuple(px(6.5, 3.0)) != (255, 255, 255)
    # The floor under the wardrobe (5.0, 5.65) is seen by no camera: black.
    assert tuple(px(5.0, 5.65)) == (0, 0, 0)
    # The colour scale: the legend panel right of the map holds both ends of viridis.
    panel = image[:, 80 * 5 :].reshape(-1, 3)
    for colour in (VIRIDIS_BRIGHT, VIRIDIS_DARK):
        assert np.any(np.all(panel == colour, axis=1)), colour
    # Its upper end follows max_std: a scale of 1 m makes the whole seen map bright.
    bright = client.get(
        f"/api/v1/maps/coverage?space_id={space}&format=png&scale=5&max_std=1", headers=admin
    )
    image2 = cv2.imdecode(np.frombuffer(bright.content, np.uint8), cv2.IMREAD_COLOR)
    assert image2[:300, :400].astype(int).sum() > image[:300, :400].astype(int).sum()
    too_big = f"/api/v1/maps/coverage?space_id={space}&format=png&spacing=0.02&scale=40"
    assert client.get(too_big, headers=admin).status_code == 422


def test_coverage_uses_the_running_twins_scene(client, admin):
    # The twin running in this space with a home that has an extra full-height wall across the
    # living room at y = 3: its scene, not the default one, gives the occluders.
    data = default_scene().model_dump(mode="json")
    data["walls"].append({"name": "extra", "start": [0.0, 3.0], "end": [4.5, 3.0], "height": 2.9})
    scene = load_scene(data)
    space = _register(client, admin, scene)
    client.app.state.runtime.twin = SimpleNamespace(space_id=space, scene=scene)
    try:
        body = client.get("/api/v1/maps/coverage", headers=admin).json()
    finally:
        client.app.state.runtime.twin = None
    expected = coverage_map(
        _cameras(scene), (0.0, 8.0), (0.0, 6.0), spacing=0.1, occluders=scene_occluders(scene)
    )
    assert len(body["occluders"]) == 23
    assert body["n_cameras"] == expected.n_cameras.tolist()
    default = coverage_map(
        _cameras(scene),
        (0.0, 8.0),
        (0.0, 6.0),
        spacing=0.1,
        occluders=scene_occluders(default_scene()),
    )
    assert body["n_cameras"] != default.n_cameras.tolist()
