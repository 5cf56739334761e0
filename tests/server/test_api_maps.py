"""The coverage-and-accuracy map over the space's floor, as JSON and as a PNG heat map."""

from __future__ import annotations

import cv2
import numpy as np

from core.localization import NetworkCamera, coverage_map

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
    assert image.shape == (12 * 4, 16 * 4, 3)

    assert client.get("/api/v1/maps/coverage?spacing=0", headers=admin).status_code == 422
    assert client.get("/api/v1/maps/coverage?format=gif", headers=admin).status_code == 422
